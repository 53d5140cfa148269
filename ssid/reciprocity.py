"""Reciprocity check of measured FRFs: Maxwell-Betti, ``H_ab = H_ba`` between driven points.

A linear structure with symmetric M, C, K (what SSID identifies) has a symmetric FRF matrix:
the acceleration at ``a`` per unit force at ``b`` equals the acceleration at ``b`` per unit
force at ``a``. Every pair of driven DOFs of a multi-shaker test measures both, from
different shakers, force gauges and accelerometers, so their agreement is the test's own
check of its calibration and linearity - the check a modal test engineer makes before
trusting a MIMO data set.

What a disagreement says:

* a constant complex **gain** ``rho = H_ab / H_ba`` other than 1: a calibration off at one
  of the four transducers (with force gauge ``F'_k = a_k F_k`` and accelerometer
  ``A'_k = b_k A_k``, ``rho = (b_a a_a) / (b_b a_b)``), or a sensor whose sign or axis is
  wrong (``rho`` = -1);
* a **shape** difference left after the gain (FRAC below 1, a residual beyond the noise and
  above :data:`ssid.frf_compare.SHAPE_TOLERANCE` of the FRF):
  a non-linear structure or fixture, an accelerometer not at the force's point or axis, a
  shaker exciting more than its axis.

Both are judged as :mod:`ssid.frf_compare` judges two measurements of one FRF: against the
noise the acquisition stated (``H_var``) and a calibration tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from .frf import FRFData
from .frf_compare import CALIBRATION_TOLERANCE, CurveComparison, compare_curves
from .noise import roughness_weights

__all__ = ["CALIBRATION_TOLERANCE", "NOISE_ONLY_SNR", "ReciprocityPair", "reciprocity_check"]

#: RMS signal-to-noise ratio below which a cross FRF is taken as noise only. Two such (drive
#: points that hardly couple: directions of a structure that move independently) say nothing
#: of reciprocity: their gain and FRAC are those of two noise records (0.017 and 0.0003 on a
#: simulated X-Z pair), which read as a calibration fault. A noise-only record has an RMS SNR
#: near 1; a resonance measured with 1e-3 noise, hundreds.
NOISE_ONLY_SNR = 2.0
#: Judged so only where the drive points' own SNR is at least this: on a grid too coarse for
#: the resonances a curve's roughness is its curvature, and a coupled pair's cross FRFs read
#: SNR 1.0 as noise does (the 14-DOF chain on 12 lines, whose H(2,7) is 0.1 of its drive
#: points); the drive points then read low too.
NOISE_ONLY_DRIVE_SNR = 10.0
#: And only below this ratio of the cross FRFs' RMS to the weaker drive point's (uncoupled
#: directions under noise of 1e-3: 0.01).
NOISE_ONLY_CROSS_TO_DRIVE = 0.1


@dataclass(frozen=True)
class ReciprocityPair:
    """The reciprocity of one pair of driven DOFs.

    Attributes
    ----------
    dof_a, dof_b : str
        The two driven DOFs; ``H_ab`` is the response at ``dof_a`` to the force at ``dof_b``.
    curves : CurveComparison
        ``H_ab`` against ``H_ba`` over the lines where both are valid: the gain ``rho`` in
        ``H_ab ~ rho H_ba`` (1 for reciprocal data), its standard deviation, FRAC and the
        residual after the gain in units of the stated noise.
    silent_drive_points : tuple of str
        Those of the two DOFs whose drive-point FRF ``H_aa`` is zero at every one of those
        lines as well (looked at only when both cross FRFs are zero): a channel that measured
        nothing, rather than two DOFs that do not couple.
    snr : (float, float)
        RMS signal-to-noise ratio of ``H_ab`` and ``H_ba``, against the stated variances or,
        without them, each curve's roughness (:func:`ssid.noise.roughness_weights`).
    cross_to_drive : float
        RMS of the larger cross FRF over that of the weaker drive point ``H_aa``, ``H_bb``.
    drive_snr : float
        The lower RMS signal-to-noise ratio of the two drive points, judged as ``snr``.
    """

    dof_a: str
    dof_b: str
    curves: CurveComparison
    silent_drive_points: tuple[str, ...] = ()
    snr: tuple[float, float] = (float("inf"), float("inf"))
    cross_to_drive: float = float("inf")
    drive_snr: float = 0.0

    @property
    def noise_only(self) -> bool:
        """Both cross FRFs at their noise level (:data:`NOISE_ONLY_SNR`), where the drive
        points show that level is noise (:data:`NOISE_ONLY_DRIVE_SNR`), and small beside them
        (:data:`NOISE_ONLY_CROSS_TO_DRIVE`): not testable."""
        return (max(self.snr) < NOISE_ONLY_SNR and self.drive_snr >= NOISE_ONLY_DRIVE_SNR
                and self.cross_to_drive < NOISE_ONLY_CROSS_TO_DRIVE)

    @property
    def reciprocal(self) -> bool:
        """The gain within the calibration tolerance or its noise, and no shape difference
        both beyond the noise and above the shape tolerance (without variances: FRAC >= 0.99);
        or both cross FRFs noise only, which nothing contradicts."""
        return self.curves.agree or self.noise_only

    def describe(self) -> str:
        """One line for a terminal: the pair, the gain, FRAC and the verdict."""
        c, a, b = self.curves, self.dof_a, self.dof_b
        if c.both_zero:
            # The same curve both ways: reciprocal. Where the drive points respond, the two
            # DOFs do not couple (directions of a structure that move independently); a dead
            # channel would be zero in its drive point too, and only then is there a doubt.
            head = (f"reciprocity {a} <-> {b}: H({a},{b}) and H({b},{a}) are both zero at all "
                    f"{c.n_lines} lines: reciprocal")
            if not self.silent_drive_points:
                return head + " (the two drive points do not couple)"
            dead = self.silent_drive_points
            return head + (f"; the drive point{'s' if len(dead) > 1 else ''} "
                           + " and ".join(f"H({d},{d})" for d in dead)
                           + f" {'are' if len(dead) > 1 else 'is'} zero too (a dead channel?)")
        if c.dead:
            return (f"reciprocity {a} <-> {b}: NOT RECIPROCAL: H({a},{b}) or H({b},{a}) is zero at all "
                    f"{c.n_lines} lines (a dead channel?)")
        head = f"reciprocity {a} <-> {b}: {c.describe()} over {c.n_lines} lines"
        if self.noise_only and not c.agree:
            return (f"reciprocity {a} <-> {b}: H({a},{b}) and H({b},{a}) are at their noise level (RMS "
                    f"signal-to-noise {self.snr[0]:.2g} and {self.snr[1]:.2g}) over {c.n_lines} lines: not "
                    "testable (the two drive points hardly couple)")
        if self.reciprocal:
            return head + ": reciprocal"
        why = []
        if not c.gain_ok:
            why.append(f"H({a},{b}) is {abs(c.gain):.3f} times H({b},{a})"
                       + (" with the opposite sign (a sensor's sign or axis?)" if c.gain.real < 0 else
                          " (a force gauge or accelerometer calibration at these points?)"))
        if not c.shape_ok:
            why.append("their shapes differ beyond the noise (non-linearity, a sensor off the drive point or axis?)")
        return head + ": NOT RECIPROCAL: " + "; ".join(why)


def _pair(frf: FRFData, a: int, b: int) -> ReciprocityPair | None:
    """Pair of inputs ``a``, ``b`` (indices into ``frf.inputs``); None without a common line."""
    io = frf.input_index()
    h, g = frf.H[:, io[a], b], frf.H[:, io[b], a]
    ok = frf.valid_mask()[:, io[a], b] & frf.valid_mask()[:, io[b], a] & np.isfinite(h) & np.isfinite(g)
    if not ok.any():
        return None
    var_h = var_g = None
    if frf.H_var is not None:
        var_h, var_g = frf.H_var[ok, io[a], b], frf.H_var[ok, io[b], a]
    curves = compare_curves(h[ok], g[ok], var_h, var_g)
    silent: tuple[str, ...] = ()
    if curves.both_zero:
        # Over the valid, finite values of each drive point: a blanked line is no response.
        def responds(k: int) -> bool:
            d = frf.H[:, io[k], k]
            return bool(np.any(np.where(frf.valid_mask()[:, io[k], k] & np.isfinite(d), d, 0.0)))

        silent = tuple(frf.inputs[k] for k in (a, b) if not responds(k))
    snr = (_snr(h[ok], var_h), _snr(g[ok], var_g))
    drives = [frf.H[ok, io[k], k] for k in (a, b)]
    drive_var = [None if frf.H_var is None else frf.H_var[ok, io[k], k] for k in (a, b)]
    drive_snr = min(_snr(d, v) for d, v in zip(drives, drive_var))
    drive = min(_rms(d) for d in drives)
    ratio = max(_rms(h[ok]), _rms(g[ok])) / drive if drive > 0 else float("inf")
    return ReciprocityPair(frf.inputs[a], frf.inputs[b], curves, silent, snr, ratio, drive_snr)


def _rms(h: np.ndarray) -> float:
    h = h[np.isfinite(h)]
    return float(np.sqrt(np.mean(np.abs(h) ** 2))) if h.size else 0.0


def _snr(h: np.ndarray, var: np.ndarray | None) -> float:
    """RMS signal-to-noise ratio of one curve ``(n_lines,)``: against its stated variances
    where every one is positive, else against its roughness along frequency (a noise-only
    curve is all roughness: about 1)."""
    if var is not None and np.all(np.isfinite(var) & (var > 0)):
        return float(np.sqrt(np.mean(np.abs(h) ** 2 / var)))
    if h.size < 3 or not np.any(h):
        return float("inf")  # no level to judge by; zero curves are judged as such
    w = roughness_weights(h[:, None, None], np.ones((h.size, 1, 1), dtype=bool))[:, 0, 0]
    return float(np.sqrt(np.mean(np.abs(h * w) ** 2)))


def reciprocity_check(frf: FRFData) -> list[ReciprocityPair]:
    """Reciprocity of every pair of driven DOFs of ``frf`` (each input is also an output).

    Parameters
    ----------
    frf : FRFData
        Accelerances ``H: (n_freq, n_out, n_in)``, with ``valid`` and ``H_var`` used where
        present.

    Returns
    -------
    list of ReciprocityPair
        One per pair of inputs with a line where both values are valid, in input order;
        empty for a single input.
    """
    out = []
    for a, b in combinations(range(frf.n_in), 2):
        pair = _pair(frf, a, b)
        if pair is not None:
            out.append(pair)
    return out
