"""Whether a line or a period is in steady state: the transient left, bounded from the data.

The record after a change of frequency (or level) is the new steady state plus a free
transient that decays like ``e^{-sigma t}`` (``sigma = zeta omega`` of the modes it excites).
Windows of ``n_w`` samples (the dwell: ``min_cycles`` periods, at least ``min_dwell_s``)
slide over the record in steps of ``n_w / 4``; each window gives the response vector per
unit force ``Y_k``. With one dominant transient mode the window errors form a geometric
sequence, ``e_k = q e_{k-1}``, and the differences ``D_k = Y_k - Y_{k-1}`` show it:

    q ~= <D_{k-1}, D_k> / <D_{k-1}, D_{k-1}>,      |e_k| ~= |q| / |1 - q| |D_k|

The line stops settling as soon as this remaining error is below ``accuracy`` (relative)
or below the noise of the estimate itself. ``|q|`` is never taken below the decay of the
lightest damping expected (``damping_guess``), nor below the slowest decay any one entry
of y shows above the noise, so that a fast-decaying transient cannot hide a slow one.
Before a line stops, that bound is checked against a multi-pole fit of the windows
(:func:`multipole_transient`), which tells close modes ringing together apart; the line
settles when both are below the target, and states the fit's error per channel.
The time spent therefore follows the physics: a few windows far from resonances, longer
where a lightly damped mode was just excited strongly.

Periodic excitation (periodic and burst random) is judged by the same single-decay
reasoning on the differences of successive periods (:func:`periodic_transient`). Both
compare what remains with the noise floor measured with every drive off (:func:`noise_floor`).
"""

from __future__ import annotations

import math

import numpy as np

from .control import raise_if_interrupted
from .rig import Rig
from .setup import ChannelSpec
from .storage import RunFile

__all__ = ["MULTIPOLE_ORDERS", "MULTIPOLE_SPANS", "TransientMonitor", "WINDOW_STEPS", "geometric_tail_gain",
           "multipole_transient", "noise_floor", "periodic_transient", "record_noise_floor"]

WINDOW_STEPS = 4  # window advance = n_w / WINDOW_STEPS

#: Spans (latest window differences used) and orders (poles) of the multi-pole fits.
MULTIPOLE_SPANS = (8, 12, 16, 24, 32)
MULTIPOLE_ORDERS = (1, 2, 3, 4, 5, 6)
#: A multi-pole fit is kept only if the latest TAIL_STEPS differences it predicts are within
#: TAIL_RATIO times those measured (plus their noise).
TAIL_STEPS, TAIL_RATIO = 3, 3.0


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
        data = rig.acquire(n)
        v = np.maximum(np.var(data - data.mean(axis=1, keepdims=True), axis=1), q)
        if var is not None and np.all(v > 0.8 * var):
            return v
        var = v
    return var


def record_noise_floor(rig: Rig, channels: list[ChannelSpec], rf: RunFile) -> tuple[np.ndarray, float]:
    """:func:`noise_floor`, kept in the run file as ``/acq/noise_floor/session<k>`` (``k``
    this session's number: a resumed run measures it again, the structure may have been
    touched); returns it and the test time it took (s)."""
    t0 = rig.clock
    nf = noise_floor(rig, channels)
    rf.write_arrays("noise_floor", {f"session{len(rf.meta.get('sessions', []))}": nf})
    return nf, (rig.clock - t0) / rig.fs_hz


def geometric_tail_gain(mag, angle):
    """``|q / (1 - q)|`` for ``q = mag exp(j angle)``: the error still to come in a sequence
    whose steps shrink by ``q`` each (``e_k = q e_(k-1)``) is this gain times its last step
    ``|D_k|``. Scalars or arrays. (``|1 - q| >= 1 - mag`` always; the ``max`` only keeps
    rounding from going below it.)"""
    return mag / np.maximum(np.abs(1 - mag * np.exp(1j * angle)), 1 - mag)


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
            # A fit holds only if it accounts for the latest differences. Poles fitted to the
            # large early differences can predict a tail far above the one measured, once the
            # transient has sunk into the noise: extrapolated, they state the early decay, not
            # what is left (a 0.5 %-damped mode driven at resonance: latest differences
            # predicted 1e-3, measured 3e-5 at a noise of 1.6e-5, and a stated error 60 times
            # the actual one, which a second shaker's nearly parallel forces amplified again).
            tail = V[-TAIL_STEPS:, seen] @ B[seen]
            if np.linalg.norm(tail) > TAIL_RATIO * (np.linalg.norm(Ds[-TAIL_STEPS:])
                                                     + math.sqrt(TAIL_STEPS) * d_noise):
                continue
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
        #: the fit's error (norm) where the last difference was below the noise, 0 where no
        #: pole showed above it (None: no fit, or the last difference was visible)
        self.fitted_below_noise: float | None = None

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
        # The norm of y follows its largest entries: a slow mode's transient can fill an entry
        # near a node of the forced response while a fast one fills the norm (the QA's weak
        # 3-DOF system at 63.75 Hz with damping_guess 0.05: differences shrinking by 0.27 a step
        # in the norm, by 0.7 in H(2+Z,1+Z); the line stopped after three and stated that
        # value's error 5.8 times low). What an entry shows the structure does is believed
        # over the guess.
        env = max(env, self._entry_decay(d_noise))
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

    def _entry_decay(self, d_noise: float) -> float:
        """The slowest decay per step shown by any one entry of y: its latest differences
        over the ones before (the envelope over six steps once there are as many), where
        they stand above the noise; 0 where no entry's do."""
        D = np.abs(np.diff(np.array(self.ys[-7:]), axis=0))
        if len(D) < 2:
            return 0.0
        a, b = (D[-6:-3].max(axis=0), D[-3:].max(axis=0)) if len(D) >= 6 else (D[-2], D[-1])
        seen = b > 3 * d_noise
        if not seen.any():
            return 0.0
        # An entry rising out of the noise (a slow transient two faster ones had cancelled in
        # the step before) shows no decay at all.
        ratio = b[seen] / np.maximum(a[seen], 3 * d_noise)
        return float(np.max(ratio ** (1 / 3) if len(D) >= 6 else ratio))

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
        (``fitted``) and gives ``shape``; below it, its error (0 where it sees no pole any
        more) is kept as ``fitted_below_noise`` for :meth:`stated_error`."""
        e = multipole_transient(np.array(self.ys), self.d_noise)
        self.fitted, self.fitted_below_noise = None, None
        if e is None:
            return self.ehat
        en = float(np.linalg.norm(e))
        self.ehat = max(self.ehat, en)
        if self.big is not None and self.big[0] == len(self.ys) - 1:  # last difference visible
            if en > 0:
                self.fitted, self.shape = e, e**2 / en**2
        else:
            self.fitted_below_noise = en  # (0: no pole shows above the noise any more)
        return self.ehat

    def stated_error(self) -> float:
        """The remaining error to state as uncertainty: the multi-pole fit's where it holds
        (within 1.3 times of the truth on the payload's lines near its 78 Hz modes, where
        the single-decay bound, the settling criterion, was up to 12 times high away from
        the resonance and 1.7 times low at it), else the bound.

        Where the transient has sunk into the noise (the last difference below it), what is
        left is the larger of the fit's extrapolation of the decay it showed before (none
        where no pole shows above the noise) and what a mode decaying as slowly as the bound
        assumes (the envelope's decay, never faster than the lightest damping expected) could
        hide below the noise: the noise of a difference times that decay's tail gain. (With
        the lightest damping's decay alone, a ``damping_guess`` heavier than the structure's
        understated it: z 3.9 on a mode decaying 0.95 a step against a guessed 0.6.) The
        single-decay bound, which settles the line, also carries the slowest decay back to
        the last visible difference: stated, it was 88 times the noise of a difference on a
        50 Hz resonance line measured with a second shaker attached, whose differences had
        shrunk by 0.15 a step into the noise, where what the noise can hide is 7.5 times it
        (``tests/test_daq_estimate.py``).
        """
        if self.fitted is not None:
            return float(np.linalg.norm(self.fitted))
        if self.fitted_below_noise is not None:
            hidden = self.d_noise * float(geometric_tail_gain(self.r, 0.0))
            return min(self.ehat, max(self.fitted_below_noise, hidden))
        return self.ehat

    def excess(self) -> float:
        """The part of :meth:`stated_error` above the noise (the noise is in the fit's
        variance already)."""
        return math.sqrt(max(self.stated_error() ** 2 - self.noise ** 2, 0.0))


def periodic_transient(periods: list[np.ndarray], n_samples: int, noise_var: np.ndarray,
                       groups: list[list[int]], accuracy: float) -> float:
    """Transient left in the last period of a periodic excitation, over what it may keep.

    Each change of the multisine starts a transient: every mode rings from the state the old
    signal left, and a ring that has not died out within a period leaks into every line of
    its rectangular window. In period k the transient at a line is a sum of geometric
    sequences (one per mode, decay ``z = exp(lambda T)`` per period), so the same
    single-decay reasoning as a stepped-sine dwell (:class:`TransientMonitor`)
    bounds what remains from the differences of successive periods: ``e_k = q / (1 - q) D_k``
    with ``q`` the complex step ratio at the line, its magnitude never below the envelope
    decay over all lines (a fast ring must not hide a slow one).

    Parameters
    ----------
    periods : list of (n_ch, n_bins) complex arrays
        Spectra (rect window, scaled by 1/n) of the last three or four periods at the band's
        bins, oldest first.
    n_samples : int
        Samples per period.
    noise_var : (n_ch,) array
        Per-sample noise floor of each channel (:func:`noise_floor`).
    groups : list of channel index lists
        Channels whose accuracy is asked together (forces, responses, reactions): a line's
        transient is compared with that group's level at the line.
    accuracy : float
        Relative accuracy asked of each line.

    Returns
    -------
    float
        Largest ratio of the remaining transient to ``accuracy`` times the group's level, over
        the lines and groups where the last difference stands above the noise (0: nothing
        does; <= 1: settled). ``inf`` with fewer than three periods.
    """
    if len(periods) < 3:
        return math.inf
    diffs = [b - a for a, b in zip(periods[:-1], periods[1:])]
    worst = 0.0
    for g in groups:
        # White noise of variance v per sample gives E|X|^2 = v / n at a bin of a period's
        # spectrum scaled by 1/n; a difference of two periods carries twice that.
        d_noise = math.sqrt(2.0 * float(np.sum(noise_var[g])) / n_samples)
        d = [np.linalg.norm(D[g], axis=0) for D in diffs]
        seen = d[-1] > 3 * d_noise  # lines where the last difference is transient, not noise
        if not seen.any():
            continue
        ratios = [math.sqrt(np.sum(b[a > 3 * d_noise] ** 2) / np.sum(a[a > 3 * d_noise] ** 2))
                  for a, b in zip(d[:-1], d[1:]) if np.any(a > 3 * d_noise)]
        env = max(ratios) if ratios else 1.0
        Dp, D = diffs[-2][g][:, seen], diffs[-1][g][:, seen]
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.sum(np.conj(Dp) * D, axis=0) / np.sum(np.abs(Dp) ** 2, axis=0)
        q = np.nan_to_num(q, nan=env)
        mag = np.clip(np.maximum(np.abs(q), env), 0.0, 0.99)
        gain = geometric_tail_gain(mag, np.angle(q))
        level = accuracy * np.linalg.norm(periods[-1][g][:, seen], axis=0)
        with np.errstate(divide="ignore"):
            worst = max(worst, float(np.max(gain * d[-1][seen] / level)))
    return worst
