"""Safety: what stops a line, what stops a run, and the words that say why.

Two levels:

* a **limit** (response acceleration, drive voltage, force, reaction load) exceeded aborts
  the current line: the drive is ramped to zero, the line is measured once more from a
  drive below what the exceeding record says reaches the limit, and if that too exceeds a
  limit the line is recorded as aborted with the reason, and the run goes on with the next
  line (:class:`LineAborted`, :mod:`daq.stepped_sine`). A DAQ over-range that persists
  through a stepped-sine line's corrections aborts it too, without a second attempt
  (:class:`LineOverRange`: the corrections already lowered its drive). (A target that
  would exceed a limit is not applied: the level control holds the line below it,
  :mod:`daq.sine_line`);
* an **instrument fault** (amplifier interlock or fault, lost heartbeat, an instrument that
  stops answering, a CAN frame gap or bus-off, a DAQ overload on several stepped-sine lines
  or random averages in a row, or with the drives off) stops the run
  (:class:`RunStopped`). Every exit path - normal end, fault, Ctrl-C, any exception - then
  goes through :meth:`daq.rig.Rig.safe_state`: all generator outputs off, all amplifiers
  disabled, acquisition stopped.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.errors import (
    AmplifierFault,
    BusOff,
    ConnectionLost,
    FramesLost,
    HeartbeatLost,
    InstrumentError,
    InstrumentTimeout,
    InterlockOpen,
    SensorOverload,
    StreamError,
)

from .rms_limit import RMS_WINDOW_S
from .setup import Limits

__all__ = ["MAX_OVER_RANGE_IN_ROW", "NOT_THE_SAME_INSTRUMENTS", "RANDOM_LIMIT_STOP", "LineAborted", "LineOverRange",
           "RunStopped", "check_limits", "describe_fault", "drive_headroom_vpp", "limit_usage", "over_range_in_row",
           "resume_remedy"]


class LineAborted(Exception):
    """A limit was exceeded during a line; the drive has to go to zero for this line.

    ``drive_vpp`` is the drive the line had when it was aborted (the record keeps it: the
    level control may have moved far from the line's first drive). ``headroom_vpp`` is the
    drive at which the record that exceeded a limit would have reached it, every channel
    scaling with the drive (:func:`drive_headroom_vpp`); inf when not known."""

    def __init__(self, reason: str, drive_vpp: float, headroom_vpp: float = math.inf) -> None:
        super().__init__(reason)
        self.drive_vpp = drive_vpp
        self.headroom_vpp = headroom_vpp


class LineOverRange(LineAborted):
    """The DAQ flagged a channel over its input range during a line (``fault``: the
    :class:`~drivers.errors.SensorOverload` it raised)."""

    def __init__(self, fault: SensorOverload, drive_vpp: float) -> None:
        super().__init__(f"{fault}: the line cannot be measured at this level", drive_vpp)
        self.fault = fault


#: A DAQ over-range costs a stepped-sine line a re-read (or its abort) and a random run an
#: average, measured again; this many sub-lines or averages in a row stop the run: a sensor
#: or cable stuck at its rail would otherwise abort every line or reject every average.
MAX_OVER_RANGE_IN_ROW = 3


def over_range_in_row(fault: SensorOverload, n: int, what: str) -> SensorOverload:
    """The fault that stops a run after ``n`` ``what`` (sub-lines, averages) in a row met
    ``fault``."""
    return SensorOverload(f"{fault}, on {n} {what} in a row (a sensor or cable at its rail, or a range too "
                          "small for the level)", fault.channels)


class RunStopped(Exception):
    """The run was stopped safely (instruments in the safe state); the message says why.

    ``cause`` is the driver error behind it, if any. The run file stays resumable.
    """

    def __init__(self, message: str, cause: BaseException | None = None) -> None:
        super().__init__(message)
        self.cause = cause


#: The words a stop's state begins with, by the kind of fault (first match wins).
_FAULT_WORDS = (
    (InterlockOpen, "amplifier interlock open"),
    (HeartbeatLost, "amplifier heartbeat lost"),
    (AmplifierFault, "amplifier fault"),
    (SensorOverload, "DAQ overload"),
    (FramesLost, "CAN frame gap"),
    (BusOff, "CAN bus-off or DAQ silent"),
    (StreamError, "DAQ stream broken"),
    (InstrumentTimeout, "instrument lost (no reply)"),
    (ConnectionLost, "instrument lost (link down)"),
    (InstrumentError, "instrument error"),
)
#: How a resume that met other instruments than the run's last session stops.
NOT_THE_SAME_INSTRUMENTS = "not the instruments of the run's last session"
#: How a random run's stop by a limit begins: its drive is fixed for the run, so a resume
#: drives as hard and meets the limit again.
RANDOM_LIMIT_STOP = "limit exceeded during random excitation"
#: What a run's state says when an instrument did not confirm the safe state (at a pause or
#: at the run's end): the UI and the remedy read it from the run file.
SAFE_STATE_NOT_CONFIRMED = "safe state not confirmed"
#: A run's state is kept in its file cut to this many characters.
STATE_MAX_CHARS = 500


def describe_fault(exc: BaseException) -> str:
    """One line naming the kind of fault and the instrument's own message."""
    for cls, words in _FAULT_WORDS:
        if isinstance(exc, cls):
            return f"{words}: {exc}"
    return f"{type(exc).__name__}: {exc}"


def _words(cls: type) -> str:
    return next(words for c, words in _FAULT_WORDS if c is cls)


def resume_remedy(state: str | None, sim: bool) -> str | None:
    """What has to change before a resume of a run that stopped with ``state`` (its run file's
    ``/acq`` state) can get further than the stop, or None.

    ``"range_volt"``: a DAQ overload stopped it, and the same range would meet the same
    overload (raise the channel's range in the setup); ``"address"``: an instrument could not
    be reached, and it may answer at another address after a restart; ``"reset_faults"``: an
    amplifier tripped (interlock, fault, heartbeat), and its latched fault refuses the next
    enable until it is reset once the cause is gone (``ssidlab check --reset-faults``);
    ``"new_instruments"``: other instruments answered than in the run's last session (fix
    the addresses, or resume with ``--new-instruments`` if one was replaced); ``"new_run"``:
    a limit stopped a random run, whose drive a resume may not change (``daq.resume``): at
    the same drive the next average exceeds it again, and only a new run, at a lower
    ``drive_vpp`` or under limits the test allows, gets further. None after any
    other stop, and when the safe state was not confirmed: the instruments come first then.
    On a simulated lab (``sim``), neither addresses nor latches outlive the run: a resume
    starts the lab afresh.

    Decided from the state text, so that a UI that has only the run file gives the same
    advice as the command line that saw the fault.
    """
    if not state or not state.startswith("stopped: ") or SAFE_STATE_NOT_CONFIRMED in state:
        return None
    fault = state.removeprefix("stopped: ")
    if fault.startswith(_words(SensorOverload)):
        return "range_volt"
    if fault.startswith(_words(ConnectionLost)) and not sim:
        return "address"
    if fault.startswith(tuple(_words(c) for c in (InterlockOpen, HeartbeatLost, AmplifierFault))) and not sim:
        return "reset_faults"
    if fault.startswith(NOT_THE_SAME_INSTRUMENTS):
        return "new_instruments"
    if fault.startswith(RANDOM_LIMIT_STOP):
        return "new_run"
    return None


_LIMITED = (("response", "max_accel_m_per_s2", "m/s^2", "acceleration"),
            ("force", "max_force_n", "N", "force"),
            ("reaction", "max_reaction_n", "N", "reaction load"))
#: The RMS limits (random excitation only, over ``RMS_WINDOW_S``), checked after the peaks:
#: the peak limit is the backstop, and a record over both is named by its peak.
_LIMITED_RMS = (("response", "max_accel_rms_m_per_s2", "m/s^2", "acceleration RMS"),
                ("force", "max_force_rms_n", "N", "force RMS"),
                ("reaction", "max_reaction_rms_n", "N", "reaction load RMS"))


def check_limits(limits: Limits, peaks: np.ndarray, roles: dict[str, list[int]], drive_vpp: float,
                 names: list[str], ranges: np.ndarray | None = None, rms: np.ndarray | None = None) -> str | None:
    """The first limit exceeded by a record (``peaks``: largest |sample| per channel), or None.

    With ``ranges`` (each channel's DAQ input range in its unit) a channel above its range
    counts as over a limit too: for predicted peaks (the DAQ flags measured ones itself).
    With ``rms`` (each channel's RMS over the last :data:`~daq.rms_limit.RMS_WINDOW_S`, a
    random run's) the RMS limits are checked too; without it they are not (stepped sine,
    whose setup may not have them)."""
    if drive_vpp > limits.max_drive_vpp * (1 + 1e-9):
        return f"drive {drive_vpp:.4g} Vpp above the limit {limits.max_drive_vpp:g} Vpp"
    checks = [(peaks, t, "") for t in _LIMITED]
    if rms is not None:
        checks += [(rms, t, f" over the last {RMS_WINDOW_S:g} s") for t in _LIMITED_RMS]
    for values, (role, attr, unit, what), over in checks:
        idx = roles.get(role, [])
        lim = getattr(limits, attr)
        if not idx or not np.isfinite(lim):
            continue
        p = values[idx]
        k = int(np.argmax(p))
        if p[k] > lim:
            return f"{what} {p[k]:.4g} {unit}{over} on {names[idx[k]]!r} above the limit {lim:g} {unit}"
    if ranges is not None:
        k = int(np.argmax(peaks / ranges))
        if peaks[k] > ranges[k]:
            return f"{peaks[k]:.4g} on {names[k]!r}, over its DAQ input range {ranges[k]:.4g}"
    return None


def _channel_limits(limits: Limits, roles: dict[str, list[int]], n_ch: int) -> np.ndarray:
    """Each channel's limit in its own unit (m/s^2 or N) from ``[limits]``, ``(n_ch,)``; inf
    for a channel no limit applies to."""
    out = np.full(n_ch, math.inf)
    for role, attr, _unit, _what in _LIMITED:
        out[roles.get(role, [])] = getattr(limits, attr)
    return out


def drive_headroom_vpp(limits: Limits, amplitudes: np.ndarray, roles: dict[str, list[int]],
                       drive_vpp: float, ranges: np.ndarray | None = None) -> float:
    """The drive (Vpp) at which the first limited channel would reach its limit (or, with
    ``ranges``, its DAQ input range), every channel scaling with the drive from
    ``amplitudes`` (per channel) measured at ``drive_vpp``; inf where no limited channel
    has a finite limit and a level."""
    a = np.asarray(amplitudes, float)
    caps = _channel_limits(limits, roles, a.size)
    if ranges is not None:
        caps = np.minimum(caps, ranges)
    live = (a > 0) & np.isfinite(caps)
    return drive_vpp * float(np.min(caps[live] / a[live])) if np.any(live) else math.inf


def limit_usage(limits: Limits, peaks: np.ndarray, roles: dict[str, list[int]], drive_vpp: float,
                rms: np.ndarray | None = None) -> dict[str, float]:
    """How much of each limit a record used: largest peak / limit per kind (1.0 = at the limit).

    Keys ``drive``, ``acceleration``, ``force``, ``reaction load``, and with ``rms`` (each
    channel's largest RMS over the window, a random run's) ``acceleration RMS``, ``force
    RMS``, ``reaction load RMS``; a kind without channels or without a finite limit is left
    out. What an engineer watches to see a line coming close to a limit before it aborts.
    """
    used = {"drive": float(drive_vpp / limits.max_drive_vpp)}
    kinds = [(peaks, t) for t in _LIMITED] + ([(rms, t) for t in _LIMITED_RMS] if rms is not None else [])
    for values, (role, attr, _unit, what) in kinds:
        idx = roles.get(role, [])
        lim = getattr(limits, attr)
        if idx and np.isfinite(lim) and lim > 0:
            used[what] = float(np.max(np.asarray(values)[idx]) / lim)
    return used
