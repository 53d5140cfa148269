"""What the TUI does with a run besides drawing: check the instruments before it (F4), decide
which run file it writes (new, resumed or refused), start ``ssidlab acquire`` as a
subprocess, steer it (pause, resume, abort), and turn its output into progress and live
curves.

No device logic here: the acquisition is ``python -m ssidlab acquire --events
--control-stdin`` (``daq``). It runs in its own process, owned by one TUI worker thread,
because that is what makes "always reaches the safe state" hold whatever happens to the UI:

* abort is SIGINT, exactly Ctrl-C of ``ssidlab acquire`` (drive to zero at once, instruments
  safe, file resumable), effective mid-line;
* pause / resume are lines on the run's stdin, honoured between lines (``daq.control``);
* if the TUI dies - closed, killed, its terminal gone - the run's stdin reaches end of input
  and the run stops safely by itself (``--control-stdin``); a thread in the UI's process
  would die with it, drive on;
* the simulated lab's physics does not share the UI's interpreter (and its GIL).
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from daq.control import parse_event_line as parse_event  # the run's event lines (ssidlab acquire --events)
from daq.safety import SAFE_STATE_NOT_CONFIRMED, STATE_MAX_CHARS

__all__ = ["EXIT_BAD_INPUT", "NO_INSTRUMENTS", "NO_LINE", "Acquisition", "LiveRun", "ProgressParser", "RunOutcome",
           "error_text", "naming", "one_line", "parse_event", "printable", "run_file_choice", "run_file_state"]

#: ``ssidlab acquire`` refused its input (setup, run file, options) before measuring anything.
EXIT_BAD_INPUT = 2

#: Exit statuses of ``ssidlab acquire`` (docs/acquisition.md).
EXIT_TEXT = {0: "complete", EXIT_BAD_INPUT: "refused (bad input)", 3: "stopped safely by a fault",
             130: "interrupted (safe)"}

#: The Run tab's side panels before a run's first line, and before its first instrument state.
NO_LINE = "no line measured yet"
NO_INSTRUMENTS = "instruments: waiting for the run"

# The one line a refused or failed command writes (ssidlab/cli.py): "ssidlab acquire: error: ..."
_ERROR_LINE = re.compile(r"^ssidlab\b[^:]*: ((?:internal )?error: .*\S)\s*$")


def error_text(line: str) -> str | None:
    """The ``error: ...`` (or ``internal error: ...``) part of a command's error line, else None."""
    m = _ERROR_LINE.match(line)
    return m.group(1) if m else None


def printable(text: str) -> str:
    """``text`` with each control character (a NUL in a typed path, a tab) written as its escape."""
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)


def one_line(exc: BaseException) -> str:
    """An error as one line of a status field (its lines joined; its type if it says nothing)."""
    return printable(" ".join(str(exc).splitlines())) or type(exc).__name__


def naming(path: str, exc: BaseException) -> str:
    """An error on ``path`` as one line that names the file (some, as a NUL byte's, do not)."""
    if isinstance(exc, OSError) and exc.strerror:  # "[Errno 2] ...: 'path'" said once, plainly
        return f"{printable(path)}: {exc.strerror}"
    why = one_line(exc)
    return why if path in str(exc) else f"{printable(path)}: {why}"


class Acquisition:
    """One ``ssidlab acquire SETUP [--sim] --out FILE --events --control-stdin`` subprocess,
    stdout and stderr merged."""

    def __init__(self, setup_path: str | Path, out: str | Path, *, sim: bool = True, resume: bool = False,
                 new_instruments: bool = False) -> None:
        self.setup_path = str(setup_path)
        self.out = str(out)
        self.sim = sim
        self.resume_file = resume  # continue the unfinished run file ``out`` (daq.resume says what may differ)
        self.new_instruments = new_instruments and resume  # take on a replaced instrument
        self.proc: subprocess.Popen[str] | None = None
        self.abort_requested = False
        # A quit may come between the run's creation and its worker's start: once shutdown
        # has begun, start must not spawn a run that nothing would stop (checked under the lock).
        self._lock = threading.Lock()
        self._closing = False

    @property
    def argv(self) -> list[str]:
        where = ["--resume", self.out] if self.resume_file else ["--out", self.out]
        argv = [sys.executable, "-m", "ssidlab", "acquire", self.setup_path, *where, "--events", "--control-stdin"]
        if self.sim:
            argv.append("--sim")
        if self.new_instruments:
            argv.append("--new-instruments")
        return argv

    def start(self) -> bool:
        """Start the subprocess; False (nothing started) once :meth:`shutdown` has begun."""
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        with self._lock:
            if self._closing:
                return False
            # Own session: a Ctrl-C typed into the terminal reaches the TUI only; the TUI decides.
            self.proc = subprocess.Popen(self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                         stdin=subprocess.PIPE, text=True, bufsize=1, env=env,
                                         start_new_session=True)
        return True

    def _send(self, command: str) -> bool:
        if not self.running or self.proc is None or self.proc.stdin is None:
            return False
        try:
            self.proc.stdin.write(command + "\n")
            self.proc.stdin.flush()
        except (BrokenPipeError, ValueError, OSError):  # the run has just ended
            return False
        return True

    def pause(self) -> bool:
        """Ask the run to pause after the current line (outputs off, amplifiers disabled)."""
        return self._send("pause")

    def resume(self) -> bool:
        return self._send("resume")

    def lines(self) -> Iterator[str]:
        """The subprocess's output lines until it closes its output."""
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            yield line.rstrip("\n")

    def wait(self, timeout: float | None = None) -> int:
        assert self.proc is not None
        return self.proc.wait(timeout)

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def abort(self) -> bool:
        """Ask the run to stop as Ctrl-C would (SIGINT). False if it is not running."""
        if not self.running:
            return False
        self.abort_requested = True
        assert self.proc is not None
        try:
            self.proc.send_signal(signal.SIGINT)
        except ProcessLookupError:
            return False
        return True

    def shutdown(self, grace_s: float = 15.0) -> None:
        """Stop and reap the subprocess: SIGINT (safe stop), then SIGKILL after ``grace_s``.
        A subprocess not started yet never starts."""
        with self._lock:
            self._closing = True
        if self.proc is None:
            return
        if self.proc.poll() is None:
            # One signal only: end of input would be a second interrupt while the run is
            # already reaching its safe state (daq holds such signals back, but one is cleaner).
            self.abort()
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._close_stdin()
        if self.proc.stdout is not None:
            self.proc.stdout.close()

    def _close_stdin(self) -> None:
        if self.proc is not None and self.proc.stdin is not None and not self.proc.stdin.closed:
            try:
                self.proc.stdin.close()
            except OSError:
                pass


_SINE = re.compile(r"^\s*shaker\s+(\d+)\s+([0-9.eE+-]+)\s+Hz\b")
_RANDOM = re.compile(r"^\s*average\s+(\d+)/(\d+)\b")


class ProgressParser:
    """Fraction done (0..1) from the acquisition's progress lines, or None if a line says nothing.

    Stepped sine: each shaker sweeps the band in turn (log spacing over frequency); random:
    ``average k/N``. The sweep's refinement makes the stepped-sine fraction an estimate.
    """

    def __init__(self, excitation: str, f_min_hz: float, f_max_hz: float, n_shakers: int) -> None:
        self.excitation = excitation
        self.f_min, self.f_max = float(f_min_hz), float(f_max_hz)
        self.n_shakers = max(1, int(n_shakers))
        self.best = 0.0

    @classmethod
    def for_setup(cls, setup) -> ProgressParser:
        if setup.excitation == "stepped_sine":
            f0, f1 = setup.sine.f_min_hz, setup.sine.f_max_hz
        else:
            f0, f1 = setup.random.f_min_hz, setup.random.f_max_hz
        return cls(setup.excitation, f0, f1, len(setup.shakers))

    def feed(self, line: str) -> float | None:
        m = _RANDOM.match(line)
        if m:
            frac = int(m.group(1)) / max(1, int(m.group(2)))
        else:
            m = _SINE.match(line)
            if not m:
                return None
            p, f = int(m.group(1)), float(m.group(2))
            if not (self.f_max > self.f_min > 0 and f > 0):
                return None
            part = math.log(f / self.f_min) / math.log(self.f_max / self.f_min)
            frac = (p + min(max(part, 0.0), 1.0)) / self.n_shakers
        # Late refinement lines go back down in frequency: never move the bar backwards.
        self.best = max(self.best, min(frac, 1.0))
        return self.best


@dataclass
class RunOutcome:
    returncode: int
    aborted: bool
    file: str
    state: str | None  # the run file's /acq state, when readable
    error: str | None = None  # the run's last "error: ..." line (error_text), the why of a refusal

    @property
    def complete(self) -> bool:
        return self.returncode == 0

    @property
    def resumable(self) -> bool:
        """Whether F5 (a resume) is the way on: an unfinished run file, and a run that got as
        far as measuring. A refused run (bad input) would be refused again until its cause
        (the setup file, the switch) has changed: its error says which."""
        return bool(self.state) and self.state != "complete" and self.returncode != EXIT_BAD_INPUT

    @property
    def safe_state_confirmed(self) -> bool:
        """Whether the run's end confirmed the safe state (every generator output off, every
        amplifier disabled), as the run file says: ``daq.run`` writes the file's last state
        after that safe state, with "safe state not confirmed" when an instrument did not
        confirm it. A file still "running" or "paused" (a run killed) or none at all confirms
        nothing, nor does a state cut at its 500 characters (its "not confirmed" may be lost)."""
        state = self.state
        return (bool(state) and state not in ("running", "paused") and "not confirmed" not in state
                and len(state) < STATE_MAX_CHARS)

    def summary(self) -> str:
        what = EXIT_TEXT.get(self.returncode, f"failed (exit status {self.returncode})")
        if self.state and SAFE_STATE_NOT_CONFIRMED in self.state:
            what = "stopped, SAFE STATE NOT CONFIRMED: check the generators and amplifiers"
        if self.aborted and self.returncode != 0:
            what = f"aborted: {what}"
        why = f": {self.error}" if self.error and self.returncode != 0 else ""
        tail = f"; run file state {self.state!r}" if self.state else ""
        return f"run {what}{why}{tail}"


def run_file_state(path: str | Path) -> str | None:
    """The ``/acq`` ``state`` attribute of a run file (read-only), or None."""
    from daq.storage import peek_run_file

    peek = peek_run_file(path)
    return peek[0] if peek else None


def run_file_choice(out: str | Path) -> tuple[str | None, bool]:
    """Whether a run may write ``out``: ``(refusal, resume)``.

    A new file starts a run; an unfinished run file is resumed (its own setup and lines are
    kept, ``ssidlab acquire --resume``); a complete run or a file that is not a run file is
    never overwritten, nor is a path whose directory does not exist. ``refusal`` is a
    one-line reason naming the file, or None."""
    try:
        # The app resolves the path to start the run: a NUL byte typed in the field (or a
        # symbolic-link loop) must be refused here, in words, not crash the app there.
        Path(out).resolve()
    except (OSError, RuntimeError, ValueError) as exc:
        return naming(str(out), exc), False
    path = Path(out)
    if not path.parent.is_dir():
        return f"{out}: directory {str(path.parent)!r} does not exist", False
    if not path.exists():
        return None, False
    state = run_file_state(path)
    if state in (None, "complete"):
        why = "holds a complete run" if state == "complete" else "exists and is not a run file"
        return f"{out} {why}: choose another run file", False
    return None, True


class LiveRun:
    """What the run's events say so far: FRF lines for the live plot, the current line's
    level, distortion and limit use, the instruments' state, paused or not.

    ``H_abs`` / ``coherence`` of a line are (n_out, n_in) with None for blanked values.
    """

    def __init__(self, outputs: list[str], inputs: list[str]) -> None:
        self.outputs, self.inputs = list(outputs), list(inputs)
        self.lines: dict[float, tuple[list, list]] = {}  # freq_hz -> (H_abs, coherence)
        # stepped sine, shaker -> freq_hz -> |response / own force| (n_out): the live view of
        # a shaker's sweep before the other shakers have measured the line
        self.sub_lines: dict[int, dict[float, list]] = {}
        self.last_line: dict | None = None  # the latest sub_line / spectrum event
        self.identities: dict = {}
        self.instruments: dict = {}
        self.paused = False
        self.simulated: bool | None = None

    def feed(self, ev: dict) -> str:
        """Take one event; returns its kind."""
        kind = str(ev.get("event"))
        if kind == "line":
            self.lines[float(ev["freq_hz"])] = (ev["H_abs"], ev["coherence"])
        elif kind == "spectrum":
            self.lines = {float(f): (h, c) for f, h, c in zip(ev["freq_hz"], ev["H_abs"], ev["coherence"],
                                                              strict=False)}
            self.last_line = ev
        elif kind == "sub_line":
            self.last_line = ev
            if ev.get("ok") and ev.get("Y_abs") is not None:
                self.sub_lines.setdefault(int(ev["shaker"]), {})[float(ev["freq_hz"])] = ev["Y_abs"]
        elif kind == "instruments":
            self.identities = ev.get("identities", {})
            self.simulated = ev.get("simulated")
        elif kind == "paused":
            self.paused = True
        elif kind == "resumed":
            self.paused = False
        if kind in ("sub_line", "spectrum") and ev.get("instruments"):
            self.instruments = ev["instruments"]
        return kind

    def curve(self, out: int, inp: int) -> tuple[list[float], list[float], list[float]]:
        """Frequency (Hz, ascending), |H| and coherence of one FRF; blanked values left out.

        Stepped sine: where a line is not complete yet (other shakers still to come), the
        shaker's own response per unit force stands in, with coherence 0 (not yet known).
        """
        pts: dict[float, tuple[float, float]] = {}
        for freq, Y in self.sub_lines.get(inp, {}).items():
            if out < len(Y) and Y[out] is not None and Y[out] > 0:
                pts[freq] = (float(Y[out]), 0.0)
        for freq, (H, coh) in self.lines.items():
            try:
                hv, cv = H[out][inp], coh[out][inp]
            except (IndexError, TypeError):
                continue
            if hv is None or not hv > 0:  # blanked, or zero: nothing to show on a log scale
                pts.pop(freq, None)
                continue
            pts[freq] = (float(hv), float(cv) if cv is not None else 0.0)
        f = sorted(pts)
        return f, [pts[x][0] for x in f], [pts[x][1] for x in f]

    def line_text(self) -> str:
        """The current line for the status panel: level, drive, distortion, limit use."""
        ev = self.last_line
        if not ev:
            return NO_LINE
        if ev["event"] == "spectrum":
            head = f"average {ev['n_avg']}/{ev['averages']}"
        else:
            # a kept line's reason: its level off the target (held below a limit, or unsettled)
            note = ev.get("reason", "")
            state = ("ok" + (f": {note}" if note else "")) if ev.get("ok") else f"ABORTED: {note}"
            head = (f"shaker {ev['shaker']} {ev['freq_hz']:.2f} Hz, drive {ev['drive_vpp']:.3f} Vpp"
                    + (f", |F| {ev['force_n']:.3g} N, THD {100 * ev['thd_max']:.2f} %" if ev.get("ok") else "")
                    + f" ({state})")
        use = ev.get("limit_use") or {}
        lim = ", ".join(f"{k} {100 * v:.0f} %" for k, v in use.items() if v is not None)
        return head + ("\nof limits: " + lim if lim else "")

    @property
    def reported_instruments(self) -> bool:
        """Whether the run said it had its instruments (the ``instruments`` event, sent once
        they answer and before anything is driven)."""
        return self.simulated is not None or bool(self.identities) or bool(self.instruments)

    def ended_text(self, outcome: RunOutcome) -> str:
        """The amplifier panel once the run has ended: only what its end reported. The last
        state read before a line ("amp0 on") is no longer true, and a run that stopped is not
        known to have left the amplifiers off unless its end confirmed the safe state."""
        if outcome.state and "not confirmed" in outcome.state:
            return "run ended: SAFE STATE NOT CONFIRMED - check the generators and amplifiers"
        if not self.reported_instruments:
            return "run ended before it reported the instruments"
        if outcome.safe_state_confirmed:
            return "run ended: drives off (outputs off, amplifiers disabled: confirmed at its end)"
        return "run ended: amplifier state unknown (its end did not confirm the safe state)"

    def instrument_text(self) -> str:
        """Amplifier interlock / enable / fault state for the status panel."""
        amps = (self.instruments or {}).get("amplifiers", {})
        if self.paused:
            head = "PAUSED: outputs off, amplifiers disabled"
        else:
            head = ""
        parts = []
        for name, st in amps.items():
            if st.get("fault"):
                parts.append(f"{name} FAULT {st['fault']}")
            elif not st.get("interlock_closed", True):
                parts.append(f"{name} INTERLOCK OPEN")
            else:
                parts.append(f"{name} {'on' if st.get('enabled') else 'off'}, interlock ok")
        return "; ".join(x for x in [head, ", ".join(parts)] if x) or NO_INSTRUMENTS
