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
* a **shape** difference left after the gain (FRAC below 1, a residual beyond the noise):
  a non-linear structure or fixture, an accelerometer not at the force's point or axis, a
  shaker exciting more than its axis.

Both are judged against the noise the acquisition stated (``H_var``) where there is one, so
that a short noisy test is not called non-reciprocal for its noise, and against a
calibration tolerance, so that a long quiet test is not called so for a 0.1 % difference no
transducer is calibrated to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from .frf import FRFData

__all__ = ["CALIBRATION_TOLERANCE", "ReciprocityPair", "reciprocity_check"]

#: Gain departure from 1 that a calibration is expected to hold: accelerometers and force
#: gauges are calibrated to about 1 % each, and the gain is a ratio of four of them.
CALIBRATION_TOLERANCE = 0.02

#: Mean squared residual per line, in units of its stated variance, above which the shapes
#: differ beyond the noise: for complex Gaussian errors the mean of n lines is 1 +- 1/sqrt(n),
#: so 3 is far out for any band worth the name, and leaves room for variances stated
#: approximately (a transient bound, a few averages).
SHAPE_NOISE_RATIO = 3.0


@dataclass(frozen=True)
class ReciprocityPair:
    """The reciprocity of one pair of driven DOFs.

    Attributes
    ----------
    dof_a, dof_b : str
        The two driven DOFs; ``H_ab`` is the response at ``dof_a`` to the force at ``dof_b``.
    n_lines : int
        Lines where both values are valid.
    gain : complex
        Least-squares ``rho`` in ``H_ab ~ rho H_ba`` (1 for reciprocal data).
    gain_std : float
        Standard deviation of ``gain`` from the stated variances (NaN without them).
    frac : float
        FRAC of ``H_ab`` and ``H_ba`` over the lines (1: the same shape up to a gain).
    residual_ratio : float
        Mean ``|H_ab - rho H_ba|^2 / (var_ab + |rho|^2 var_ba)``: about 1 when what the gain
        leaves is noise (NaN without variances).
    reciprocal : bool
        The gain within the calibration tolerance or its noise, and no shape difference
        beyond the noise (or, without variances, FRAC >= 0.99).
    """

    dof_a: str
    dof_b: str
    n_lines: int
    gain: complex
    gain_std: float
    frac: float
    residual_ratio: float
    reciprocal: bool

    def describe(self) -> str:
        """One line for a terminal: the pair, the gain, FRAC and the verdict."""
        g = self.gain
        deg = round(math.degrees(np.angle(g)), 2) + 0.0  # + 0.0: no "-0.00"
        head = (f"reciprocity {self.dof_a} <-> {self.dof_b}: gain {abs(g):.4f} at {deg:+.2f} deg, "
                f"FRAC {self.frac:.4f} over {self.n_lines} lines")
        if self.reciprocal:
            return head + ": reciprocal"
        if not np.isfinite(g):
            return (f"reciprocity {self.dof_a} <-> {self.dof_b}: NOT RECIPROCAL: H({self.dof_a},{self.dof_b}) or "
                    f"H({self.dof_b},{self.dof_a}) is zero at all {self.n_lines} lines (a dead channel?)")
        why = []
        if not _gain_ok(g, self.gain_std):
            why.append(f"H({self.dof_a},{self.dof_b}) is {abs(g):.3f} times H({self.dof_b},{self.dof_a})"
                       + (" with the opposite sign (a sensor's sign or axis?)" if g.real < 0 else
                          " (a force gauge or accelerometer calibration at these points?)"))
        if not _shape_ok(self.residual_ratio, self.frac):
            why.append("their shapes differ beyond the noise (non-linearity, a sensor off the drive point or axis?)")
        return head + ": NOT RECIPROCAL: " + "; ".join(why)


def _gain_ok(gain: complex, gain_std: float) -> bool:
    off = abs(gain - 1.0)
    return off <= CALIBRATION_TOLERANCE or (np.isfinite(gain_std) and off <= 3.0 * gain_std)


def _shape_ok(residual_ratio: float, frac: float) -> bool:
    if np.isfinite(residual_ratio):
        return residual_ratio <= SHAPE_NOISE_RATIO
    return frac >= 0.99


def _pair(frf: FRFData, a: int, b: int) -> ReciprocityPair | None:
    """Pair of inputs ``a``, ``b`` (indices into ``frf.inputs``); None without a common line."""
    io = frf.input_index()
    ok = frf.valid_mask()[:, io[a], b] & frf.valid_mask()[:, io[b], a]
    h, g = frf.H[:, io[a], b], frf.H[:, io[b], a]
    ok &= np.isfinite(h) & np.isfinite(g)
    if not ok.any():
        return None
    h, g = h[ok], g[ok]
    var = None
    if frf.H_var is not None:
        vh, vg = frf.H_var[ok, io[a], b], frf.H_var[ok, io[b], a]
        if np.all(np.isfinite(vh) & np.isfinite(vg)) and np.all(vh + vg > 0):
            var = (vh, vg)
    if not (np.any(h) and np.any(g)):
        nan = float("nan")
        return ReciprocityPair(frf.inputs[a], frf.inputs[b], int(ok.sum()), complex(nan), nan, nan, nan, False)
    # Lines weighted by the noise of their difference; one pass, as the gain is near 1
    # wherever this matters (far from 1, the verdict does not hang on the weights).
    w = 1.0 / (var[0] + var[1]) if var is not None else np.ones(h.shape)
    rho = complex(np.sum(w * h * np.conj(g)) / np.sum(w * np.abs(g) ** 2))
    frac = float(np.abs(np.vdot(h, g)) ** 2 / (np.vdot(h, h).real * np.vdot(g, g).real))
    if var is not None:
        v = var[0] + abs(rho) ** 2 * var[1]
        gain_std = float(1.0 / math.sqrt(np.sum(np.abs(g) ** 2 / v)))
        residual = float(np.mean(np.abs(h - rho * g) ** 2 / v))
    else:
        gain_std = residual = float("nan")
    return ReciprocityPair(frf.inputs[a], frf.inputs[b], int(ok.sum()), rho, gain_std, frac, residual,
                           _gain_ok(rho, gain_std) and _shape_ok(residual, frac))


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
