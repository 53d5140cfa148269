"""Run control and run events: pause / resume between lines, and what a run reports as it goes.

A test engineer pausing a run wants the structure at rest while they look at it or touch
it, so a pause is not a "hold the drive": when the current line has finished, every
generator output goes off and every amplifier is disabled (the rig's safe state), the run
file says ``paused``, and the run waits. Resume re-arms the amplifiers and continues with
the next line exactly as if there had been no pause (the simulated world does not advance
while nothing is acquired; a real structure simply rests). Abort stays what it always was:
Ctrl-C / SIGINT / SIGTERM, at once, mid-line.

:class:`RunControl` holds plain flags, no locks: its methods may be called from a signal
handler or from another thread (``ssidlab acquire --control-stdin`` reads commands on a
thread). :class:`RunEvents` turns what the run measures into small JSON-able dicts for a
user interface (``ssidlab acquire --events``).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.interrupts import hold_interrupt
from ssid.jsonutil import to_jsonable

from .safety import SAFE_STATE_NOT_CONFIRMED, RunStopped

__all__ = ["EVENT_PREFIX", "RunControl", "RunEvents", "clear_interrupts", "event_line", "hold_if_paused",
           "latching_interrupt_handler", "parse_event_line", "raise_if_interrupted"]

#: Prefix of an event's line on a run's stdout (``ssidlab acquire --events``).
EVENT_PREFIX = "@event "


class RunControl:
    """Pause and resume requests for a running test, honoured between lines.

    The flags are read by the run's own thread between lines (:func:`hold_if_paused`); a
    pause asked for mid-line takes effect when the line is finished and stored.
    """

    def __init__(self) -> None:
        self._pause = False
        self.paused = False  # True while the run is actually held

    def request_pause(self) -> None:
        self._pause = True

    def request_resume(self) -> None:
        self._pause = False

    @property
    def pause_requested(self) -> bool:
        return self._pause


#: Interrupts raised by :func:`latching_interrupt_handler` and not yet handled by a run
#: (process-wide, as signal handlers are; list.append is atomic under the GIL).
_latched: list[type[BaseException]] = []


def latching_interrupt_handler(exc_type: type[BaseException] = KeyboardInterrupt) -> Callable:
    """A SIGINT / SIGTERM handler that raises ``exc_type`` at once and also remembers it.

    Python runs a signal handler between two bytecodes of the main thread, wherever that is.
    When it is inside a finalizer or a weakref callback (garbage collection may run one at
    any allocation), the exception the handler raises is printed as "Exception ignored" and
    dropped: the Ctrl-C is lost and the drive runs on (seen once in CI). The run therefore
    calls :func:`raise_if_interrupted` before every acquisition, which raises the interrupt
    again if it never arrived.

    Inside a driver's :data:`drivers.interrupts.interrupts_held` section (a wait on a lock the
    simulated DAQ or the amplifier's event loop also takes) the interrupt is raised when the
    section ends, a few milliseconds on: raised inside, it could leave that lock taken for good
    and the safe state waiting on it.
    """
    def handler(signum, frame):
        _latched.append(exc_type)
        if not hold_interrupt(exc_type):
            raise exc_type()

    _quiet_about_latched_interrupts()
    return handler


def _quiet_about_latched_interrupts() -> None:
    """Install a ``sys.unraisablehook`` that keeps quiet about an interrupt the handler raised
    inside a finalizer: Python printed it as "Exception ignored in: ..." with a traceback, on
    the command's one-line stderr, although the interrupt is latched and raised again
    (:func:`raise_if_interrupted`). Anything else goes to the hook that was there before."""
    previous = sys.unraisablehook
    if getattr(previous, "quiet_about_latched_interrupts", False):
        return

    def hook(unraisable) -> None:
        if unraisable.exc_type not in _latched:
            previous(unraisable)

    hook.quiet_about_latched_interrupts = True
    sys.unraisablehook = hook


def raise_if_interrupted() -> None:
    """Raise an interrupt that :func:`latching_interrupt_handler` raised but nobody handled."""
    if _latched:
        exc_type = _latched[-1]
        _latched.clear()
        raise exc_type()


def clear_interrupts() -> None:
    """The run has handled the interrupt (it is stopping): forget it."""
    _latched.clear()


class RunEvents:
    """Calls ``sink(event)`` with JSON-able dicts (``{"event": kind, ...}``); no sink, no cost."""

    def __init__(self, sink: Callable[[dict], None] | None = None) -> None:
        self.sink = sink

    def __bool__(self) -> bool:
        return self.sink is not None

    def emit(self, kind: str, **fields: Any) -> None:
        if self.sink is not None:
            self.sink(to_jsonable({"event": kind, **fields}))


def event_line(event: dict) -> str:
    """One event as its output line, ``@event {json}`` (compact, strict JSON)."""
    return EVENT_PREFIX + json.dumps(event, separators=(",", ":"))


def parse_event_line(line: str) -> dict | None:
    """The event of an :func:`event_line`, or None for any other (log) line."""
    if not line.startswith(EVENT_PREFIX):
        return None
    try:
        ev = json.loads(line[len(EVENT_PREFIX):])
    except ValueError:
        return None
    return ev if isinstance(ev, dict) and "event" in ev else None


def frf_line_event(freq_hz: float, H: np.ndarray, coh: np.ndarray, valid: np.ndarray) -> dict:
    """Fields of a ``line`` event: |H| (blanked values None) and coherence, (n_out, n_in)."""
    return {"freq_hz": float(freq_hz), "H_abs": np.where(valid, np.abs(H), np.nan), "coherence": coh}


def hold_if_paused(control: RunControl | None, rig, runfile, echo: Callable[[str], None],
                   events: RunEvents, where: str, poll_s: float = 0.05) -> bool:
    """Between lines: if a pause is requested, go safe, wait for resume, re-arm.

    Returns True if the run was held (the caller must treat every drive as off). Raises
    :class:`~daq.safety.RunStopped` if the safe state could not be confirmed: a pause must
    not leave a drive on behind the engineer's back. Ctrl-C while paused raises
    KeyboardInterrupt from the wait, as anywhere else in the run.
    """
    if control is None or not control.pause_requested:
        return False
    problems = rig.safe_state()
    if problems:
        raise RunStopped(f"pause: {SAFE_STATE_NOT_CONFIRMED}: {'; '.join(problems)}")
    control.paused = True
    runfile.set_state("paused")
    echo(f"paused {where}: generator outputs off, amplifiers disabled; waiting for resume")
    events.emit("paused", where=where)
    t0 = time.monotonic()
    try:
        while control.pause_requested:
            raise_if_interrupted()
            time.sleep(poll_s)
    finally:
        control.paused = False
    runfile.set_state("running")
    rig.prepare()
    echo(f"resumed after {time.monotonic() - t0:.1f} s: amplifiers enabled")
    events.emit("resumed")
    return True
