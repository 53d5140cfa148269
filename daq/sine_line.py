"""One stepped-sine line: level, settle by the measured transient decay, dwell.

Windows of ``n_w`` samples (the dwell: ``min_cycles`` periods, at least ``min_dwell_s``)
slide over the record after a change of frequency or level in steps of ``n_w / 4``; each
window gives the response vector per unit force. The line settles when the transient left
in the last window, bounded from the differences of the windows (:mod:`daq.steady_state`),
is below ``accuracy`` or the noise; the time spent therefore follows the physics.

Level control: the force (or a control accelerometer) of the first window after a change,
and again of the settled line, is compared with the target; outside ``tolerance`` the drive
is corrected (at most a factor ``compression`` per step, ramped, ``MAX_CORRECTIONS`` per
line) and settling starts again. A first window holds the change's transient, so it is
trusted only while the corrections it asks keep one direction (see ``measure``). A target
needing more than the drive limit, or a drive that would take a channel past its limit or
DAQ range (every channel scales with the drive), is not applied: the line is held below it
(``NOTCH_MARGIN``). Clipped samples drop the drive by ``compression``; a line still
clipping when its corrections are used up is aborted.
The first guess comes from the previous lines (log-log extrapolation of force per volt), so
corrections are rare except where the force drops out at resonances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from drivers.errors import SensorOverload

from .estimate import SineEstimate, SineFit
from .rig import Rig
from .control import raise_if_interrupted
from .safety import LineAborted, LineOverRange, check_limits, drive_headroom_vpp
from .setup import Limits, SineSpec
from .steady_state import WINDOW_STEPS, TransientMonitor

__all__ = ["LineResult", "SineLine", "initial_drive"]


@dataclass
class LineResult:
    """What one sub-line measured (a record row of the run file)."""

    freq_hz: float
    pattern: int
    drive_vpp: float
    est: SineEstimate
    settle_s: float
    dwell_s: float
    transient: float  # estimated remaining relative error of the transient
    decay: float  # |q| at the end (decay per window step)
    #: (n_ch,) the transient's remaining error per channel (std, channel units; see
    #: :meth:`SineLine.transient_per_channel`)
    x_transient: np.ndarray | None = None
    raw: np.ndarray | None = None
    corrections: int = 0
    #: why the level was held below the target (a limit, a DAQ range or the drive limit
    #: would have been exceeded), or ""
    limited: str = ""
    extra: dict = field(default_factory=dict)


#: Drive corrections per line at most. Each changes the drive by ``compression`` at most, so
#: a first line far from its target (the first drive is ``initial_vpp``) may need several:
#: with 4, an acceleration-controlled first line of the 14-DOF example stopped at 27 % of
#: its target.
MAX_CORRECTIONS = 10
#: The smallest drive a line is given (the generators' smallest amplitude).
MIN_DRIVE_VPP = 0.002
#: A line whose target would exceed a limit or DAQ range is held at this fraction of the
#: drive that would reach it: the room is for the peaks' noise and the step's transient.
NOTCH_MARGIN = 0.8


def initial_drive(history: list[tuple[float, float, float]], freq_hz: float, target: float,
                  spec: SineSpec, max_vpp: float) -> float:
    """First drive guess from ``history`` [(f, vpp, |control|), ...] of this shaker.

    Control gain ``|control| / vpp`` extrapolated log-log from the last two lines, the
    change from the last drive kept within ``compression``.
    """
    if not history:
        return min(spec.initial_vpp, max_vpp)
    f1, v1, a1 = history[-1]
    g = a1 / v1
    if len(history) >= 2:
        f0, v0, a0 = history[-2]
        g0 = a0 / v0
        if f1 != f0 and g0 > 0 and g > 0:
            slope = math.log(g / g0) / math.log(f1 / f0)
            slope = max(-4.0, min(4.0, slope))
            g = g * (freq_hz / f1) ** slope
    want = target / max(g, 1e-30)
    c = spec.compression
    return float(min(max(want, v1 / c, MIN_DRIVE_VPP), v1 * c, max_vpp))


class SineLine:
    """Measures sub-lines on a rig.

    Parameters
    ----------
    rig : Rig
    spec : SineSpec
    limits : Limits
    roles : dict
        Channel indices: ``force`` (per shaker), ``response``, ``reaction``.
    drive_limits_vpp : list of float
        Largest drive per shaker (``TestSetup.drive_limit_vpp``).
    control : int or None
        Channel index of the control accelerometer (None: control on the active force).
    keep_raw : bool
        Return the dwell window's samples.
    ranges : (n_ch,) array, optional
        Each channel's DAQ input range in its unit: a drive that would take a channel past it
        is not applied, like one past a limit.
    """

    def __init__(self, rig: Rig, spec: SineSpec, limits: Limits, roles: dict[str, list[int]],
                 drive_limits_vpp: list[float], control: int | None = None, keep_raw: bool = False,
                 ranges: np.ndarray | None = None) -> None:
        self.rig, self.spec, self.limits, self.roles = rig, spec, limits, roles
        self.ranges = ranges
        self.control = control
        self.keep_raw = keep_raw
        self.drive_limits_vpp = drive_limits_vpp
        self.decay_prev = 0.0
        self.noise_var: np.ndarray | None = None  # per-sample noise floor of each channel
        self.group_ref = [0.0, 0.0]  # largest |y| of responses and reactions seen so far
        self.resp = roles["response"]
        self.react = roles["reaction"]

    # ------------------------------------------------------------------ helpers
    def _sizes(self, freq_hz: float) -> tuple[int, int]:
        fs = self.rig.fs_hz
        n_w = max(self.spec.min_cycles * fs / freq_hz, self.spec.min_dwell_s * fs, 16.0)
        n_c = int(math.ceil(n_w / WINDOW_STEPS))
        return n_c * WINDOW_STEPS, n_c

    def _groups(self) -> list[list[int]]:
        """The channel groups of y in order: responses, reactions (present ones only)."""
        return [idx for idx in (self.resp, self.react) if idx]

    def _scales(self, est: SineEstimate, j: int) -> list[float]:
        """Scale of each group of y (responses, reactions; present groups only): the group's
        own size per unit force, but not below a tenth of its size on the lines so far. The
        settling monitors ask the accuracy of each group's own size whatever its scale (the
        noise bounds what they can ask); the floor lets the dwell judge the noise of a group
        near a zero (reactions passing through zero) against its usual level, not its
        momentary near-zero."""
        F = est.X[self.roles["force"][j]]
        return [max(float(np.linalg.norm(est.X[idx] / F)), 0.1 * self.group_ref[g], 1e-300)
                for g, idx in enumerate((self.resp, self.react)) if idx]

    def _y_groups(self, est: SineEstimate, j: int,
                  scales: list[float] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Responses and reactions per unit active force, each group divided by its scale
        (default :meth:`_scales` of ``est``: unit norm, so m/s^2/N and N/N weigh alike):
        ``(y, var y)`` per present group."""
        F = est.X[self.roles["force"][j]]
        vF = est.var[self.roles["force"][j]]
        out = []
        for idx, s in zip(self._groups(), self._scales(est, j) if scales is None else scales):
            y = est.X[idx] / F
            vy = (est.var[idx] + np.abs(y) ** 2 * vF) / max(abs(F) ** 2, 1e-300)
            out.append((y / s, vy / s**2))
        return out

    def _y(self, est: SineEstimate, j: int, scales: list[float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The groups of :meth:`_y_groups` in one vector, and its variance."""
        parts = self._y_groups(est, j, scales)
        return np.concatenate([y for y, _ in parts]), np.concatenate([v for _, v in parts])

    def transient_per_channel(self, mons: list[TransientMonitor], est: SineEstimate, j: int,
                              scales: list[float], y_vars: list[np.ndarray], rel: float) -> np.ndarray:
        """The transient's remaining error per channel (std, channel units), ``(n_ch,)``.

        Each group's monitor (``mons``, one per group of y: responses, reactions, each per
        unit active force divided by its scale in ``scales``) bounds the error of its group by
        its norm, and its multi-pole fit (without one, its last difference) gives its shape:
        that of the modes still ringing, not of the forced response. Shared out in proportion
        to the response instead, channels near a node of the forced response got a small
        share of an error they carry in full (payload, lines above its 78 Hz mode: errors up
        to 35 times the stated standard deviation). Each entry's share counts only above that
        entry's own noise (``y_vars``, the variance of each group's y in the last settling
        window): the part of the bound the noise accounts for is in the fit's variance
        already. A group whose differences never rose above its noise gets its bound above
        that noise, relative to its y, times each channel's amplitude. The active force
        carries none of it (y is per unit of it); other channels, which y does not hold, get
        ``rel`` (the bound above the noise, relative to y as a whole) times their amplitude.
        """
        X = np.abs(est.X)
        out = rel * X
        F = abs(est.X[self.roles["force"][j]])
        out[self.roles["force"][j]] = 0.0
        for mon, idx, s, vy in zip(mons, self._groups(), scales, y_vars):
            if mon.shape is None:
                norm_g = max(float(np.linalg.norm(X[idx])) / max(F, 1e-300) / s, 1e-300)
                out[idx] = mon.excess() / norm_g * X[idx]
            else:
                out[idx] = np.sqrt(np.maximum(mon.stated_error() ** 2 * mon.shape - vy, 0.0)) * F * s
        return out

    def remember_level(self, est: SineEstimate, j: int) -> None:
        """Update the groups' usual levels with a finished line."""
        F = est.X[self.roles["force"][j]]
        for g, idx in enumerate((self.resp, self.react)):
            if idx and abs(F) > 0:
                self.group_ref[g] = max(self.group_ref[g], float(np.linalg.norm(est.X[idx] / F)))

    def floor_decay(self, freq_hz: float, n_c: int) -> float:
        """Decay per window step of the lightest damping expected at this frequency."""
        sigma = self.spec.damping_guess * 2 * math.pi * freq_hz
        return math.exp(-sigma * n_c / self.rig.fs_hz)

    # ------------------------------------------------------------------ measurement
    def measure(self, j: int, freq_hz: float, vpp: float, target: float, *, settled_steps: bool = False) -> LineResult:
        """Measure shaker ``j`` at ``freq_hz`` starting at drive ``vpp``.

        With ``settled_steps`` every drive is settled before the level control changes it
        (no first window is trusted): for a line measured again after a limit aborted it,
        where a first window, read while the resonance builds up, understates what the
        drive will bring.

        Raises :class:`LineAborted` when a limit is exceeded (the caller ramps the drive down).
        """
        rig, spec = self.rig, self.spec
        n_w, n_c = self._sizes(freq_hz)
        fit = SineFit(freq_hz, rig.fs_hz, n_w, band_hz=rig.passband_hz)
        # The level control must not ask more than the generator takes: it refuses, and that
        # stops the run (a generator range of 4 Vpp under a set-up limit of 10 did).
        max_vpp = self.drive_limits_vpp[j]
        ctl = self.control if self.control is not None else self.roles["force"][j]
        rig.sine(j, freq_hz, vpp)
        t_start = t_all = rig.clock  # every scan of this line counts as test time, discarded ones too
        buf = np.zeros((len(rig.names), 0))
        buf0 = rig.clock  # clock of buf[:, 0]

        def new_monitor() -> TransientMonitor:
            # The accuracy is asked of each window's own size of the group. Asked of the
            # group's scale (a tenth of its largest level so far where it is smaller), the
            # lines far below a resonance were let settle to 7e-3 of their size
            # (bench/sweep_time.py --quick, where all now settle within 1e-3).
            return TransientMonitor(spec.accuracy, self.floor_decay(freq_hz, n_c), self.decay_prev)

        # One monitor per group of y (responses, reactions), each with its own noise: with one
        # for y as a whole, a noisy group (load cells far less sensitive than the
        # accelerometers) set the noise the transient was compared with, so the other group
        # stopped settling while its transient stood above its own noise, and that transient
        # went unstated (payload on its stand, 60-130 Hz, load cells 1000 times less
        # sensitive: accelerances' errors up to 11 times their stated standard deviation).
        groups = self._groups()
        mons = [new_monitor() for _ in groups]
        # A group's windows share one scale, the first window's. Scaled by each window's own
        # norm, y lost the part of the transient along itself: at a resonance the ringing
        # mode has the forced response's shape, so what remained was nearly all a change of
        # magnitude and the monitor saw a fraction of it (payload on its stand, 79.47 Hz line
        # beside a 0.29 %-damped mode: stated error 2.5 times low, line error 2.5e-3 against
        # an accuracy of 1e-3). A monitor of one group does not depend on its scale (its
        # bound, noise and threshold scale alike); the scales only put y in units in which
        # m/s^2/N and N/N compare, for the dwell and the stated uncertainty.
        scales: list[float] = []
        corrections = 0
        level_checked = False
        # The first window after a change reads the level with the change's transient in it:
        # at a resonance the force drops out only as the response builds up, so it reads high
        # after a step up and low after a step down. Corrected on those readings, the drive
        # of the free payload's 309.7 Hz line swung between 0.69 and 1.37 Vpp until the ten
        # corrections were used up, and the line was kept at 0.75 of its target. First
        # windows are trusted while they keep asking the same way (a drive far off its target,
        # e.g. the smallest first drive, is ramped there without settling in between), until
        # one asks the other way or a settled reading has corrected the drive.
        first_windows_trusted, first_way = not settled_steps, 0.0
        limited = ""  # why the line is held below its target, if it is

        def off_level(settled: bool) -> bool:
            """Correct the drive if the control level of the last window ``est`` (``settled``
            or the first after a change) is outside the tolerance (settling then starts
            again); False if it is within it, no correction is left, a first window's
            reading is not trusted, or the line is held below a target it cannot reach."""
            nonlocal first_windows_trusted, first_way, limited
            level = abs(est.X[ctl])
            if abs(level / target - 1) <= spec.tolerance or corrections >= MAX_CORRECTIONS:
                return False
            want = vpp * target / max(level, 1e-30)
            new_vpp = float(min(max(want, vpp / spec.compression, MIN_DRIVE_VPP), vpp * spec.compression, max_vpp))
            # Every channel scales with the drive: the target's drive is not approached when
            # it would take a channel past its limit or DAQ range. Stepped into, it was caught
            # only once exceeded (a x2 step from 44 N put 88 N on a 50 N force limit), and its
            # transient clipped the DAQ, which stopped the run.
            headroom = drive_headroom_vpp(self.limits, est.peak, self.roles, vpp, self.ranges)
            if not settled:
                way = math.copysign(1.0, want - vpp)
                # (a first window asking beyond a channel's limit is read again once settled;
                # new_vpp stops at the drive limit)
                first_windows_trusted &= way * first_way >= 0 and new_vpp != vpp and want <= headroom
                if not first_windows_trusted:
                    return False
                first_way = way
            else:
                first_windows_trusted = False
                limited = ""  # the last settled reading says whether the target is out of reach
                if want > min(headroom, max_vpp) * (1 + 1e-9):
                    # The target cannot be held: the line is measured below it, at the drive
                    # that keeps every channel within NOTCH_MARGIN of its limit and range
                    # (notching, as a vibration controller's limit channels do). Aborted
                    # instead, every line whose target needed more was lost: the payload
                    # under 2 m/s^2 at 6+Z lost 42 sub-lines, and the FRFs 1345 values.
                    if headroom < max_vpp:
                        over = check_limits(self.limits, est.peak * (want / vpp), self.roles, max_vpp, rig.names,
                                            self.ranges) or "a channel past its limit"
                        limited = f"the target needs {want:.4g} Vpp, which would put {over}"
                    else:
                        limited = (f"the target needs {want:.4g} Vpp, more than {max_vpp:g} Vpp "
                                   "(max_drive_vpp, or the generator's max_vpp)")
                    held = min(max_vpp, NOTCH_MARGIN * headroom)
                    new_vpp = float(min(max(held, vpp / spec.compression, MIN_DRIVE_VPP), vpp * spec.compression))
                    if abs(new_vpp / vpp - 1) <= spec.tolerance:
                        return False  # held where the limits allow
            set_drive(new_vpp)
            return True

        def set_drive(new_vpp: float) -> None:
            """A corrected drive: settling (and the level's check) start again."""
            nonlocal vpp, corrections, level_checked, buf, buf0, mons, scales
            vpp = new_vpp
            rig.sine(j, freq_hz, vpp)
            corrections += 1
            level_checked = False
            buf, buf0 = np.zeros((len(rig.names), 0)), rig.clock
            mons, scales = [new_monitor() for _ in groups], []

        while True:
            try:
                buf = np.hstack([buf, self._acquire(n_w if buf.shape[1] < n_w else n_c, vpp)])
            except LineOverRange:
                # Clipped samples say only that the level was too high: the drive goes down
                # and the line is read again. The first window of a line far above the last
                # (a mode between two lines) clipped so, and so did the ringing an aborted line
                # left (payload, 2 m/s^2 at 6+Z, 1361-1479 Hz): aborting such lines at once, as
                # tried, three in a row stopped the run. Only a line still clipping is aborted.
                if corrections >= MAX_CORRECTIONS or vpp <= MIN_DRIVE_VPP:
                    raise
                first_windows_trusted = False
                set_drive(max(vpp / spec.compression, MIN_DRIVE_VPP))
                continue
            start = buf0 + buf.shape[1] - n_w
            est = fit.fit(buf[:, -n_w:], start=start - t_start, noise_var=self.noise_var)
            if not level_checked:
                level_checked = True
                if off_level(settled=False):
                    continue
            if not scales:
                scales = self._scales(est, j)
            parts = self._y_groups(est, j, scales)
            for mon, (y, vy) in zip(mons, parts):
                mon.update(y, float(np.sqrt(np.sum(vy))))
            # The groups must be settled at once; the multi-pole fits are run only when every
            # group's bound already says so.
            if all(mon.bound_met() for mon in mons) and all(mon.settled() for mon in mons):
                # The first window's level was the transient's too: the settled one is held.
                if off_level(settled=True):
                    continue
                break
            if (buf.shape[1] - n_w) / rig.fs_hz >= spec.max_settle_s:
                for mon in mons:
                    mon.conclude()
                break
        self.decay_prev = max((mon.r for mon in mons), default=0.0)  # the slowest decay seen
        self.remember_level(est, j)
        est, rec = self._dwell(fit, est, buf, buf0, t_start, j, n_w, freq_hz, vpp)
        n_used = rec.shape[1]
        norm_y = max(float(np.sqrt(sum(np.sum(np.abs(y) ** 2) for y, _ in parts))), 1e-300)
        # Only the part of the transient bound above the noise is extra uncertainty: when
        # the line stopped because the transient sank into the noise, the noise says it all.
        excess = min(math.sqrt(sum(mon.excess() ** 2 for mon in mons)), norm_y)
        return LineResult(
            freq_hz=freq_hz, pattern=j, drive_vpp=vpp, est=est,
            settle_s=(rig.clock - t_all - n_used) / rig.fs_hz, dwell_s=n_used / rig.fs_hz,
            transient=excess / norm_y, decay=self.decay_prev,
            x_transient=self.transient_per_channel(mons, est, j, scales, [vy for _, vy in parts], excess / norm_y),
            raw=rec if self.keep_raw else None, corrections=corrections, limited=limited)

    def _acquire(self, n: int, vpp: float) -> np.ndarray:
        """The next ``n`` scans at drive ``vpp``; the line is aborted when they went over a
        DAQ input range or a limit."""
        raise_if_interrupted()  # a Ctrl-C swallowed elsewhere (daq.control)
        try:
            data = self.rig.acquire(n)
        except SensorOverload as exc:
            # Before the limits: clipped samples understate the peaks they are checked on.
            raise LineOverRange(exc, vpp) from None
        peaks = np.max(np.abs(data), axis=1)
        reason = check_limits(self.limits, peaks, self.roles, vpp, self.rig.names)
        if reason:
            raise LineAborted(reason, vpp, drive_headroom_vpp(self.limits, peaks, self.roles, vpp))
        return data

    def _dwell(self, fit: SineFit, est: SineEstimate, buf: np.ndarray, buf0: int, t_start: int, j: int,
               n_w: int, freq_hz: float, vpp: float) -> tuple[SineEstimate, np.ndarray]:
        """Lengthen the dwell when noise, not the transient, limits the accuracy."""
        y, vy = self._y(est, j)
        rel = float(np.sqrt(np.sum(vy))) / max(float(np.linalg.norm(y)), 1e-300)
        if rel <= self.spec.accuracy:
            return est, buf[:, -n_w:]
        fs = self.rig.fs_hz
        n_need = int(min(n_w * (rel / self.spec.accuracy) ** 2, self.spec.max_dwell_s * fs))
        if n_need <= n_w:
            return est, buf[:, -n_w:]
        more = self._acquire(n_need - n_w, vpp)
        rec = np.hstack([buf[:, -n_w:], more])
        start = buf0 + buf.shape[1] - n_w - t_start
        long_fit = SineFit(freq_hz, fs, rec.shape[1], band_hz=self.rig.passband_hz)
        return long_fit.fit(rec, start=start, noise_var=self.noise_var), rec
