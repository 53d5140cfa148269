"""Two measurements of the same FRF: do they agree within their noise and a calibration?

The statistics behind the data-quality checks of a vibration test. Reciprocity compares
``H_ab`` with ``H_ba`` (:mod:`ssid.reciprocity`); linearity and repeatability compare one
test's FRFs with another's at another force level or on another day
(:func:`compare_frfs`). In each, a disagreement is either a constant complex **gain**
(a calibration: linear in everything, so no shape changes) or a **shape** difference left
after the gain (a resonance that moved or widened: a non-linear joint, a structure that
changed between runs, a sensor off its point). Both are judged against the noise the
acquisition stated (``H_var``) where there is one and against a calibration tolerance, so
that a short noisy test is not called inconsistent for its noise and a long quiet one not for
a 0.1 % difference no transducer is calibrated to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .frf import FRFData, require_response

__all__ = ["CALIBRATION_TOLERANCE", "SHAPE_NOISE_RATIO", "SHAPE_TOLERANCE", "CurveComparison", "FRFComparison",
           "compare_curves", "compare_frfs"]

#: Gain departure from 1 that calibrations are expected to hold: accelerometers and force
#: gauges are calibrated to about 1 % each, and a gain compares ratios of several of them.
CALIBRATION_TOLERANCE = 0.02

#: Mean squared residual per line, in units of its stated variance, above which two curves'
#: shapes differ beyond the noise: for complex Gaussian errors the mean of n lines is
#: 1 +- 1/sqrt(n), so 3 is far out for any band worth the name, and leaves room for
#: variances stated approximately (a transient bound, a few averages).
SHAPE_NOISE_RATIO = 3.0

#: Relative rms residual after the gain, ``||a - rho b|| / ||a||``, below which two curves
#: have the same shape whatever their stated noise. A finding must matter as well as stand
#: out of the noise (as the gain has ``CALIBRATION_TOLERANCE``): 1e-3 is the relative
#: accuracy a stepped sine is asked for by default, and a tenth of the amplitude linearity
#: transducers are specified to. Without it, data whose stated noise is far below 1e-3 (a
#: noise-free simulation, very long averages) would be called different for effects of
#: 1e-5 that no engineer would act on.
SHAPE_TOLERANCE = 1e-3


@dataclass(frozen=True)
class CurveComparison:
    """Curve ``a`` against curve ``b`` over their common valid lines.

    Attributes
    ----------
    n_lines : int
        Lines where both are valid.
    gain : complex
        Least-squares ``rho`` in ``a ~ rho b``, lines weighted by the noise of their
        difference (NaN when either curve is zero at every line).
    gain_std : float
        Standard deviation of ``gain`` from the stated variances (NaN without them).
    frac : float
        FRAC of the two curves (1: the same shape up to a gain).
    residual_ratio : float
        Mean ``|a - rho b|^2 / (var_a + |rho|^2 var_b)``: about 1 when what the gain leaves is
        noise (NaN without variances).
    relative_residual : float
        ``||a - rho b|| / ||a||`` over the lines: how large what the gain leaves is.
    """

    n_lines: int
    gain: complex
    gain_std: float
    frac: float
    residual_ratio: float
    relative_residual: float

    @property
    def dead(self) -> bool:
        """Either curve is zero at every line (a dead channel)."""
        return not np.isfinite(self.gain)

    @property
    def gain_ok(self) -> bool:
        """The gain is 1 within the calibration tolerance or within 3 of its standard deviations."""
        off = abs(self.gain - 1.0)
        return off <= CALIBRATION_TOLERANCE or (np.isfinite(self.gain_std) and off <= 3.0 * self.gain_std)

    @property
    def shape_ok(self) -> bool:
        """What the gain leaves is noise, or too small to matter (without variances: FRAC >= 0.99)."""
        if np.isfinite(self.residual_ratio):
            return self.residual_ratio <= SHAPE_NOISE_RATIO or self.relative_residual <= SHAPE_TOLERANCE
        return self.frac >= 0.99

    @property
    def agree(self) -> bool:
        return not self.dead and self.gain_ok and self.shape_ok

    def describe(self) -> str:
        """``gain 1.0000 at +0.00 deg, FRAC 1.0000``: the numbers an engineer reads first."""
        deg = round(math.degrees(np.angle(self.gain)), 2) + 0.0  # + 0.0: no "-0.00"
        return f"gain {abs(self.gain):.4f} at {deg:+.2f} deg, FRAC {self.frac:.4f}"

    def to_json_dict(self) -> dict:
        """The comparison's numbers as plain JSON values (the gain as magnitude and phase)."""
        return {"n_lines": self.n_lines, "gain_abs": abs(self.gain),
                "gain_phase_deg": float(np.degrees(np.angle(self.gain))), "gain_std": self.gain_std,
                "frac": self.frac, "residual_ratio": self.residual_ratio,
                "relative_residual": self.relative_residual, "agree": self.agree}


def compare_curves(a: np.ndarray, b: np.ndarray, var_a: np.ndarray | None = None,
                   var_b: np.ndarray | None = None) -> CurveComparison:
    """Compare two complex curves over the same lines, ``(n_lines,)`` each, all valid.

    ``var_a``, ``var_b``: the variance of each value, used only when both are finite
    everywhere and their sum is positive at every line.
    """
    a, b = np.asarray(a, complex), np.asarray(b, complex)
    nan = float("nan")
    if not (np.any(a) and np.any(b)):
        return CurveComparison(a.size, complex(nan), nan, nan, nan, nan)
    var = None
    if var_a is not None and var_b is not None:
        va, vb = np.asarray(var_a, float), np.asarray(var_b, float)
        if np.all(np.isfinite(va) & np.isfinite(vb)) and np.all(va + vb > 0):
            var = (va, vb)
    # One weighting pass, as the gain is near 1 wherever the verdict hangs on it.
    w = 1.0 / (var[0] + var[1]) if var is not None else np.ones(a.shape)
    rho = complex(np.sum(w * a * np.conj(b)) / np.sum(w * np.abs(b) ** 2))
    frac = float(np.abs(np.vdot(a, b)) ** 2 / (np.vdot(a, a).real * np.vdot(b, b).real))
    relative = float(np.linalg.norm(a - rho * b) / np.linalg.norm(a))
    if var is None:
        return CurveComparison(a.size, rho, nan, frac, nan, relative)
    v = var[0] + abs(rho) ** 2 * var[1]
    return CurveComparison(a.size, rho, float(1.0 / math.sqrt(np.sum(np.abs(b) ** 2 / v))), frac,
                           float(np.mean(np.abs(a - rho * b) ** 2 / v)), relative)


@dataclass(frozen=True)
class FRFComparison:
    """Every FRF of one test (``a``) against the same FRF of another (``b``).

    ``curves[i][j]`` compares output ``outputs[i]`` per input ``inputs[j]`` over the
    ``freq_hz`` lines both tests measured; None where no line is valid in both.
    """

    freq_hz: np.ndarray
    outputs: list[str]
    inputs: list[str]
    curves: list[list[CurveComparison | None]]

    def disagreeing(self) -> list[tuple[str, str, CurveComparison]]:
        """``(output, input, comparison)`` of every FRF that does not agree."""
        return [(o, i, c) for o, row in zip(self.outputs, self.curves) for i, c in zip(self.inputs, row)
                if c is not None and not c.agree]

    def n_compared(self) -> int:
        return sum(c is not None for row in self.curves for c in row)


def compare_frfs(a: FRFData, b: FRFData, rtol_hz: float = 1e-9) -> FRFComparison:
    """Compare each FRF of ``a`` with the same (output, input) FRF of ``b``.

    Parameters
    ----------
    a, b : FRFData
        Accelerances ``H: (n_freq, n_out, n_in)`` of two tests of one structure (e.g. at two
        force levels); FRFs are matched by output and input label, lines by frequency
        (within ``rtol_hz`` relative: an adaptive stepped sine may measure other lines in
        another run). ``valid`` and ``H_var`` are used where present.

    Raises
    ------
    InputError
        No output and input label in common, no frequency line in common, or no valid
        value in common (every common value blanked or non-finite in one of the two).
    """
    require_response(a, "first FRF data")
    require_response(b, "second FRF data")
    outputs = [o for o in a.outputs if o in b.outputs]
    inputs = [i for i in a.inputs if i in b.inputs]
    if not outputs or not inputs:
        raise InputError("the two FRF files share no output and input DOF labels")
    # Common lines: each of a's lines and b's nearest, where that is within the tolerance.
    hi = np.clip(np.searchsorted(b.freq_hz, a.freq_hz), 0, b.n_freq - 1)
    lo = np.maximum(hi - 1, 0)
    k_b = np.where(np.abs(b.freq_hz[lo] - a.freq_hz) < np.abs(b.freq_hz[hi] - a.freq_hz), lo, hi)
    same = np.abs(b.freq_hz[k_b] - a.freq_hz) <= rtol_hz * a.freq_hz
    if not same.any():
        raise InputError("the two FRF files have no frequency line in common")
    ka, kb = np.flatnonzero(same), k_b[same]
    va, vb = a.valid_mask(), b.valid_mask()
    curves: list[list[CurveComparison | None]] = []
    for o in outputs:
        row = []
        ia, ib = a.outputs.index(o), b.outputs.index(o)
        for i in inputs:
            ja, jb = a.inputs.index(i), b.inputs.index(i)
            ha, hb = a.H[ka, ia, ja], b.H[kb, ib, jb]
            ok = va[ka, ia, ja] & vb[kb, ib, jb] & np.isfinite(ha) & np.isfinite(hb)
            if not ok.any():
                row.append(None)
                continue
            var_a = None if a.H_var is None else a.H_var[ka, ia, ja][ok]
            var_b = None if b.H_var is None else b.H_var[kb, ib, jb][ok]
            row.append(compare_curves(ha[ok], hb[ok], var_a, var_b))
        curves.append(row)
    if all(c is None for row in curves for c in row):
        # Otherwise "all 0 FRFs agree": nothing was compared, which is no agreement.
        raise InputError(f"the two FRF files have no valid value in common ({len(ka)} common "
                         "frequency lines, every value blanked or non-finite in one of them)")
    return FRFComparison(a.freq_hz[ka], outputs, inputs, curves)
