"""One stepped-sine line: level, settle by the measured transient decay, dwell.

The record after a change of frequency (or level) is the new steady state plus a free
transient that decays like ``e^{-sigma t}`` (``sigma = zeta omega`` of the modes it excites).
Windows of ``n_w`` samples (the dwell: ``min_cycles`` periods, at least ``min_dwell_s``)
slide over the record in steps of ``n_w / 4``; each window gives the response vector per
unit force ``Y_k``. With one dominant transient mode the window errors form a geometric
sequence, ``e_k = q e_{k-1}``, and the differences ``D_k = Y_k - Y_{k-1}`` show it:

    q ~= <D_{k-1}, D_k> / <D_{k-1}, D_{k-1}>,      |e_k| ~= |q| / |1 - q| |D_k|

The line stops settling as soon as this remaining error is below ``accuracy`` (relative)
or below the noise of the estimate itself. ``|q|`` is never taken below the decay of the
lightest damping expected (``damping_guess``), so that a fast-decaying transient cannot
hide a slow one. Before a line stops, that bound is checked against a multi-pole fit of
the windows (:func:`multipole_transient`), which tells close modes ringing together apart;
the line settles when both are below the target, and states the fit's error per channel.
The time spent therefore follows the physics: a few windows far from resonances, longer
where a lightly damped mode was just excited strongly.

Level control: the force (or a control accelerometer) of the first window after a change,
and again of the settled line, is compared with the target; outside ``tolerance`` the drive
is corrected (at most a factor ``compression`` per step, ramped, ``MAX_CORRECTIONS`` per
line) and settling starts again. The first guess comes from
the previous lines (log-log extrapolation of force per volt), so corrections are rare
except where the force drops out at resonances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .estimate import SineEstimate, SineFit
from .rig import Rig
from .control import raise_if_interrupted
from .safety import LineAborted, check_limits
from .setup import ChannelSpec, Limits, SineSpec

__all__ = ["LineResult", "SineLine", "TransientMonitor", "geometric_tail_gain", "initial_drive", "noise_floor"]

WINDOW_STEPS = 4  # window advance = n_w / WINDOW_STEPS


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
    extra: dict = field(default_factory=dict)


def noise_floor(rig: Rig, channels: list[ChannelSpec], seconds: float = 0.25, max_wait_s: float = 3.0) -> np.ndarray:
    """Per-sample noise variance of each channel with every drive off (the noise floor).

    Measured once the structure is at rest: while a chunk's variance is still falling
    (a ringdown - after an interrupted run, a knock on the structure), the next chunk is
    taken, up to ``max_wait_s``. Taken during a ringdown, the "noise" would be the decay of
    the structure and every line would dwell for its maximum. Two chunks of noise alone
    differ by a few per cent; a ringdown of 2 % damping below 100 Hz loses more than a fifth
    of its energy per chunk.

    Never below the 24-bit quantisation step's variance (``(range / 2^23)^2 / 12``).
    """
    n = max(64, int(seconds * rig.fs_hz))
    ranges_volt = np.array([c.range_volt for c in channels])
    sens_v_per_unit = np.array([c.sensitivity_mv_per_unit / 1e3 for c in channels])
    q = (ranges_volt / 2**23 / sens_v_per_unit) ** 2 / 12
    var = None
    for _ in range(max(1, int(np.ceil(max_wait_s / seconds)))):
        raise_if_interrupted()  # a Ctrl-C swallowed elsewhere (daq.control)
        data, _ = rig.acquire(n)
        v = np.maximum(np.var(data - data.mean(axis=1, keepdims=True), axis=1), q)
        if var is not None and np.all(v > 0.8 * var):
            return v
        var = v
    return var


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
    return float(min(max(want, v1 / c, 0.002), v1 * c, max_vpp))


def geometric_tail_gain(mag, angle):
    """``|q / (1 - q)|`` for ``q = mag exp(j angle)``: the error still to come in a sequence
    whose steps shrink by ``q`` each (``e_k = q e_(k-1)``) is this gain times its last step
    ``|D_k|``. Scalars or arrays. (``|1 - q| >= 1 - mag`` always; the ``max`` only keeps
    rounding from going below it.)"""
    return mag / np.maximum(np.abs(1 - mag * np.exp(1j * angle)), 1 - mag)


#: Drive corrections per line at most. Each changes the drive by ``compression`` at most, so
#: a first line far from its target (the first drive is ``initial_vpp``) may need several:
#: with 4, an acceleration-controlled first line of the 14-DOF example stopped at 27 % of
#: its target.
MAX_CORRECTIONS = 10

#: Spans (latest window differences used) and orders (poles) of the multi-pole fits.
MULTIPOLE_SPANS = (8, 12, 16, 24, 32)
MULTIPOLE_ORDERS = (1, 2, 3, 4, 5, 6)


def multipole_transient(ys: np.ndarray, d_noise: float, spans: tuple[int, ...] = MULTIPOLE_SPANS,
                        orders: tuple[int, ...] = MULTIPOLE_ORDERS, max_decay: float = 0.995) -> np.ndarray | None:
    """Remaining transient error of the last window estimate, per entry of y, from the poles
    the window sequence shows; ``(n,)`` magnitudes, or None with fewer than 3 differences.

    Every mode still ringing adds ``c_m z_m^k`` to the k-th window estimate ``Y_k``, with the
    same pole ``z_m = exp((s_m - j omega) dt)`` on every channel (``s_m`` the mode's root,
    ``omega`` the drive, ``dt`` the window step), so ``D_k = Y_k - Y_(k-1)`` obeys one linear
    recursion ``D_k = sum_i a_i D_(k-i)`` on all channels together (Prony's method, vector
    form). Its roots are the poles; the residues ``B_m`` of ``D_k = sum_m B_m z_m^k`` are
    least squares; the error left in the last estimate is ``e_K = sum_m B_m z_m^K / (z_m - 1)``.
    Close modes ringing together (the payload on its stand: 77.4, 79.5 and 81.8 Hz at
    0.3-0.55 %) are told apart here; one decay rate and one turn per step, read from the
    differences of all of them, put the error up to 1.7 times low at the resonances and up
    to 12 times high away from them (60-130 Hz, against a long-settled truth).

    An order too low misses a mode, one too high fits the noise, a span too short sees a
    slow mode poorly: each entry takes the largest error over the fits of every span and
    order. Poles whose share of the latest difference is below ``d_noise`` (the noise of a
    difference) are fits of the noise and are left out. Written here because numpy and
    scipy have no vector Prony fit; it is two small least-squares problems per fit.
    """
    D = np.diff(np.asarray(ys), axis=0)
    if len(D) < 3 or not np.all(np.isfinite(D)):
        return None  # (a dead force gauge makes y infinite: the single-decay bound then stands)
    out = np.zeros(D.shape[1])
    for span in sorted({min(s, len(D)) for s in spans}):
        Ds = D[-span:]
        K = len(Ds)
        for p in orders:
            if K - p < 2:
                break
            # Rows: every channel at every step k >= p predicted from its p previous ones.
            A = np.stack([Ds[p - i - 1:K - i - 1] for i in range(p)], axis=-1).reshape(-1, p)
            a = np.linalg.lstsq(A, Ds[p:].reshape(-1), rcond=None)[0]
            z = np.roots(np.r_[1.0, -a])
            # A pole on or outside the unit circle is noise or a drift, not a free decay:
            # it is taken as the slowest decay believed, so that it still counts.
            z = np.where(np.abs(z) > max_decay, max_decay * z / np.maximum(np.abs(z), 1e-300), z)
            V = z[None, :] ** np.arange(K)[:, None]
            B = np.linalg.lstsq(V, Ds, rcond=None)[0]  # (p, n)
            seen = np.linalg.norm(B, axis=1) * np.abs(z) ** (K - 1) >= d_noise
            if seen.any():
                e = (B[seen] * (z[seen] ** K / (z[seen] - 1))[:, None]).sum(axis=0)
                out = np.maximum(out, np.abs(e))
    return out


class TransientMonitor:
    """Remaining transient error of a sequence of window estimates (module docstring).

    Parameters
    ----------
    accuracy : float
        Requested relative accuracy.
    floor : float
        Smallest decay per window step believed (lightest damping expected).
    prior : float
        Decay per step found at the end of the previous line (used until two differences
        give an estimate of their own).
    """

    def __init__(self, accuracy: float, floor: float, prior: float) -> None:
        self.accuracy, self.floor, self.prior = accuracy, floor, prior
        self.ys: list[np.ndarray] = []
        self.qs: list[float] = []
        self.ds: list[float] = []
        self.big: tuple[int, float] | None = None
        self.r = max(floor, prior)
        self.ehat = math.inf
        self.threshold = 0.0  # the error the current window may keep (set by update)
        self.noise = 0.0
        self.d_noise = 0.0  # noise of one window difference
        #: |D|^2 / ||D||^2 of the last difference above the noise: the transient's share per
        #: entry of y (e_k = q e_(k-1) makes each difference parallel to the error itself).
        self.shape: np.ndarray | None = None
        #: the multi-pole fit's error per entry of y at the last :meth:`conclude` (or None)
        self.fitted: np.ndarray | None = None

    def update(self, y: np.ndarray, noise: float) -> None:
        """Add the next window's vector ``y`` (and its noise); :meth:`settled` then says
        whether the line may stop."""
        self.ys.append(y)
        self.noise = noise
        k = len(self.ys) - 1
        if k == 0:
            return  # one window: no difference yet (ehat stays infinite)
        D = self.ys[-1] - self.ys[-2]
        dn = float(np.linalg.norm(D))
        self.ds.append(dn)
        # Differences of windows overlapping by 3/4 carry about this much noise.
        self.d_noise = d_noise = noise * math.sqrt(2.0 / WINDOW_STEPS)
        if k >= 2:
            Dp = self.ys[-2] - self.ys[-3]
            den = float(np.vdot(Dp, Dp).real)
            if den > (3 * d_noise) ** 2:
                self.qs.append(complex(np.vdot(Dp, D) / den))
        # The decay per step, complex: e_k = q e_{k-1} gives |e_k| = |q| / |1 - q| |D_k|. A
        # transient that turns between windows (a mode away from the drive frequency) is
        # measured well by few differences. Of the last two estimates the one giving the
        # larger error is used, never decaying faster than the lightest damping expected,
        # so that a fast transient cannot hide a slower one.
        if len(self.ds) >= 6 and max(self.ds[-6:-3]) > 0:
            # Envelope decay over six steps: robust where two transients beat.
            env = (max(self.ds[-3:]) / max(self.ds[-6:-3])) ** (1 / 3)
        elif self.qs:
            env = max(abs(q) for q in self.qs[-2:])
        else:
            env = self.prior
        mag = min(max(env, self.floor), 0.99)
        gains = [(float(geometric_tail_gain(mag, np.angle(q))), mag) for q in self.qs[-2:]]
        gain, r = max(gains) if gains else (mag / (1 - mag), mag)
        self.r = r
        # Two transients can cancel in one difference (a turning point of the error vector):
        # the last few differences, decayed to now, bound the current one.
        recent_d = max(d * r ** m for m, d in enumerate(reversed(self.ds[-4:])))
        if dn > 3 * d_noise:
            self.big = (k, recent_d)
            self.ehat = gain * recent_d
            self.shape = np.abs(D) ** 2 / dn**2
        elif self.big is not None:
            # Below the noise: bounded by the last visible difference, decayed since.
            self.ehat = min(gain * max(recent_d, d_noise), self.big[1] * r ** (k - self.big[0]) * gain)
        else:
            self.ehat = noise  # nothing ever rose above the noise: noise-limited from the start
        self.threshold = max(self.accuracy * float(np.linalg.norm(y)), noise)

    def bound_met(self) -> bool:
        """The single-decay bound (updated every window) is below the accuracy asked or the
        noise."""
        return self.ehat <= self.threshold

    def settled(self) -> bool:
        """True when the remaining error is below the accuracy asked, or below the noise:
        :meth:`bound_met` first, then the multi-pole fit (it costs more than the bound)."""
        return self.bound_met() and self.conclude() <= self.threshold

    def conclude(self) -> float:
        """The remaining error checked against :func:`multipole_transient` of the windows so
        far: ``ehat``, the bound the line settles by, becomes the larger of the two. Where
        the last difference stands above the noise, the fit's error vector is kept
        (``fitted``) and gives ``shape``; below it the fit sees no pole, and what the noise
        hides is the single-decay bound's to say (``fitted`` None)."""
        e = multipole_transient(np.array(self.ys), self.d_noise)
        self.fitted = None
        if e is not None and e.any():
            en = float(np.linalg.norm(e))
            self.ehat = max(self.ehat, en)
            if self.big is not None and self.big[0] == len(self.ys) - 1:  # last difference visible
                self.fitted, self.shape = e, e**2 / en**2
        return self.ehat

    def stated_error(self) -> float:
        """The remaining error to state as uncertainty: the multi-pole fit's where it holds
        (within 1.3 times of the truth on the payload's lines near its 78 Hz modes, where
        the single-decay bound, the settling criterion, was up to 12 times high away from
        the resonance and 1.7 times low at it), else the bound."""
        return self.ehat if self.fitted is None else float(np.linalg.norm(self.fitted))

    def excess(self) -> float:
        """The part of :meth:`stated_error` above the noise (the noise is in the fit's
        variance already)."""
        return math.sqrt(max(self.stated_error() ** 2 - self.noise ** 2, 0.0))


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
    """

    def __init__(self, rig: Rig, spec: SineSpec, limits: Limits, roles: dict[str, list[int]],
                 drive_limits_vpp: list[float], control: int | None = None, keep_raw: bool = False) -> None:
        self.rig, self.spec, self.limits, self.roles = rig, spec, limits, roles
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
    def measure(self, j: int, freq_hz: float, vpp: float, target: float) -> LineResult:
        """Measure shaker ``j`` at ``freq_hz`` starting at drive ``vpp``.

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

        def off_level() -> bool:
            """Correct the drive if the control level of the last window ``est`` is outside
            the tolerance (settling then starts again); False if it is within it or no
            correction is left."""
            nonlocal vpp, corrections, level_checked, buf, buf0, mons, scales
            level = abs(est.X[ctl])
            if abs(level / target - 1) <= spec.tolerance or corrections >= MAX_CORRECTIONS:
                return False
            want = vpp * target / max(level, 1e-30)
            if want > max_vpp * (1 + 1e-9):
                raise LineAborted(f"drive limit: the target needs {want:.4g} Vpp, more than "
                                  f"{max_vpp:g} Vpp (max_drive_vpp, or the generator's max_vpp)")
            vpp = float(min(max(want, vpp / spec.compression, 0.002), vpp * spec.compression, max_vpp))
            rig.sine(j, freq_hz, vpp)
            corrections += 1
            level_checked = False
            buf, buf0 = np.zeros((len(rig.names), 0)), rig.clock
            mons, scales = [new_monitor() for _ in groups], []
            return True

        while True:
            raise_if_interrupted()  # a Ctrl-C swallowed elsewhere (daq.control)
            data, _ = rig.acquire(n_w if buf.shape[1] < n_w else n_c)
            buf = np.hstack([buf, data])
            reason = check_limits(self.limits, np.max(np.abs(data), axis=1), self.roles, vpp, rig.names)
            if reason:
                raise LineAborted(reason)
            start = buf0 + buf.shape[1] - n_w
            est = fit.fit(buf[:, -n_w:], start=start - t_start, noise_var=self.noise_var)
            if not level_checked:
                level_checked = True
                if off_level():
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
                if off_level():
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
            raw=rec if self.keep_raw else None, corrections=corrections)

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
        raise_if_interrupted()  # a Ctrl-C swallowed elsewhere (daq.control)
        more, _ = self.rig.acquire(n_need - n_w)
        peaks = np.max(np.abs(more), axis=1)
        reason = check_limits(self.limits, peaks, self.roles, vpp, self.rig.names)
        if reason:
            raise LineAborted(reason)
        rec = np.hstack([buf[:, -n_w:], more])
        start = buf0 + buf.shape[1] - n_w - t_start
        long_fit = SineFit(freq_hz, fs, rec.shape[1], band_hz=self.rig.passband_hz)
        return long_fit.fit(rec, start=start, noise_var=self.noise_var), rec
