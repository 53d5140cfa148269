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
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .frf import FRFData, require_response
from .solvers import power_of_two_near

__all__ = ["CALIBRATION_TOLERANCE", "MIN_COMMON_LINES", "SHAPE_NOISE_RATIO", "SHAPE_TOLERANCE", "CurveComparison",
           "FRFComparison", "common_lines", "compare_curves", "compare_frfs"]

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

#: Fewest lines two curves are compared over. The gain takes one complex degree of freedom,
#: so over one line it fits exactly: FRAC is 1 and nothing is left, "agree" whatever the
#: curves. Over n lines noise alone leaves the residual of a Gamma(n - 1) sum, and calls a
#: shape different (mean above SHAPE_NOISE_RATIO) for 1 FRF in 400 at 2 lines, 1 in 5000 at
#: 5, 1 in 76,000 at 8: from 8 on, a shape verdict over a test's tens of FRFs is not noise.
MIN_COMMON_LINES = 8

#: Two lines are one frequency when they differ by less than this fraction of the local line
#: spacing (the resolution of the records): a line grid stored in float32 (relative rounding
#: 6e-8, 3e-5 Hz at 500 Hz) or written by a format that keeps six digits still matches its
#: float64 original, while a grid shifted by a part of a spacing does not.
LINE_MATCH_FRACTION = 0.01

#: Relative frequency difference always taken as the same line: float32 rounding (2**-24)
#: with a margin, for records too short to have a spacing (one line).
FLOAT32_RTOL = 4.0 * 2.0**-24


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
    both_zero : bool
        Both curves are zero at every line: they agree exactly, with no gain or FRAC to state
        (NaN). Two identically zero curves are the same curve: a cross FRF between DOFs that
        do not couple, measured both ways.
    """

    n_lines: int
    gain: complex
    gain_std: float
    frac: float
    residual_ratio: float
    relative_residual: float
    both_zero: bool = False

    @property
    def dead(self) -> bool:
        """One curve is zero at every line and the other is not (a dead channel?)."""
        return not self.both_zero and not np.isfinite(self.gain)

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
        return self.both_zero or (not self.dead and self.gain_ok and self.shape_ok)

    def describe(self) -> str:
        """``gain 1.0000 at +0.00 deg, FRAC 1.0000``: the numbers an engineer reads first."""
        if self.both_zero:
            return "both zero at every line"
        deg = round(math.degrees(np.angle(self.gain)), 2) + 0.0  # + 0.0: no "-0.00"
        g = abs(self.gain)
        # Four decimals near 1, where calibrations are judged; a scale error of decades
        # (a file in other units) as four digits and an exponent, not ninety digits.
        size = f"{g:.4f}" if 1e-3 <= g < 1e4 else f"{g:.4g}"
        return f"gain {size} at {deg:+.2f} deg, FRAC {self.frac:.4f}"

    def to_json_dict(self) -> dict:
        """The comparison's numbers as plain JSON values (the gain as magnitude and phase)."""
        return {"n_lines": self.n_lines, "gain_abs": abs(self.gain),
                "gain_phase_deg": float(np.degrees(np.angle(self.gain))), "gain_std": self.gain_std,
                "frac": self.frac, "residual_ratio": self.residual_ratio,
                "relative_residual": self.relative_residual, "both_zero": self.both_zero, "agree": self.agree}


def compare_curves(a: np.ndarray, b: np.ndarray, var_a: np.ndarray | None = None,
                   var_b: np.ndarray | None = None) -> CurveComparison:
    """Compare two complex curves over the same lines, ``(n_lines,)`` each, all valid.

    ``var_a``, ``var_b``: the variance of each value, used only when both are finite
    everywhere and their sum is positive at every line.
    """
    a, b = np.asarray(a, complex), np.asarray(b, complex)
    nan = float("nan")
    if not (np.any(a) and np.any(b)):
        return CurveComparison(a.size, complex(nan), nan, nan, nan, nan, both_zero=not (np.any(a) or np.any(b)))
    # Each curve divided by a power of two at its largest magnitude before any product: FRAC
    # forms fourth powers of |H|, which leave float64 at |H| ~ 1e77 or 1e-77 (FRAC NaN, a
    # false "differ"), while the reader accepts |H| from 1e-100 to 1e100. Every quantity below
    # is a ratio of the scaled curves and the gain takes the scales back; scaling by powers
    # of two is exact, so where nothing overflowed the numbers are bit for bit the same.
    sa, sb = power_of_two_near(np.max(np.abs(a))), power_of_two_near(np.max(np.abs(b)))
    an, bn = a / sa, b / sb
    var = None
    if var_a is not None and var_b is not None:
        va, vb = np.asarray(var_a, float), np.asarray(var_b, float)
        if np.all(np.isfinite(va) & np.isfinite(vb)) and np.all(va + vb > 0):
            var = (va, vb)
    # One weighting pass, as the gain is near 1 wherever the verdict hangs on it. The weights'
    # common factor cancels in the gain: near 1 at most, so that w |b|^2 stays finite.
    total = var[0] + var[1] if var is not None else np.ones(a.shape)
    w = power_of_two_near(np.min(total)) / total
    rho_n = complex(np.sum(w * an * np.conj(bn)) / np.sum(w * np.abs(bn) ** 2))  # an ~ rho_n bn
    rho = rho_n * (sa / sb)
    frac = float(np.abs(np.vdot(an, bn)) ** 2 / (np.vdot(an, an).real * np.vdot(bn, bn).real))
    left = an - rho_n * bn  # what the gain leaves, in units of sa
    relative = float(np.linalg.norm(left) / np.linalg.norm(an))
    if var is None:
        return CurveComparison(a.size, rho, nan, frac, nan, relative)
    # The variances in the scaled units (divided twice: sa**2 itself may leave float64).
    v = var[0] / sa / sa + abs(rho_n) ** 2 * (var[1] / sb / sb)
    gain_std = (sa / sb) / math.sqrt(np.sum(np.abs(bn) ** 2 / v))
    return CurveComparison(a.size, rho, float(gain_std), frac, float(np.mean(np.abs(left) ** 2 / v)), relative)


@dataclass(frozen=True)
class FRFComparison:
    """Every FRF of one test (``a``) against the same FRF of another (``b``).

    ``curves[i][j]`` compares output ``outputs[i]`` per input ``inputs[j]`` over the
    ``freq_hz`` lines both tests measured; None where fewer than :data:`MIN_COMMON_LINES`
    lines are valid in both. ``reaction_curves[r][j]`` compares the interface reaction
    (load cell) ``reactions[r]`` per input ``inputs[j]`` alike, for the reactions both
    records measured. ``n_unmatched`` counts the lines of the band both records cover that
    have no line in the other (grids that differ there), left out.
    """

    freq_hz: np.ndarray
    outputs: list[str]
    inputs: list[str]
    curves: list[list[CurveComparison | None]]
    n_unmatched: int = 0
    reactions: list[str] = field(default_factory=list)
    reaction_curves: list[list[CurveComparison | None]] = field(default_factory=list)

    def disagreeing(self) -> list[tuple[str, str, CurveComparison]]:
        """``(output, input, comparison)`` of every accelerance FRF that does not agree."""
        return [(o, i, c) for o, row in zip(self.outputs, self.curves) for i, c in zip(self.inputs, row)
                if c is not None and not c.agree]

    def disagreeing_reactions(self) -> list[tuple[str, str, CurveComparison]]:
        """``(reaction, input, comparison)`` of every reaction FRF that does not agree."""
        return [(r, i, c) for r, row in zip(self.reactions, self.reaction_curves)
                for i, c in zip(self.inputs, row) if c is not None and not c.agree]

    def n_compared(self) -> int:
        """Accelerance FRFs compared (reactions: :meth:`n_reactions_compared`)."""
        return sum(c is not None for row in self.curves for c in row)

    def n_reactions_compared(self) -> int:
        return sum(c is not None for row in self.reaction_curves for c in row)


def _line_spacing(freq_hz: np.ndarray) -> np.ndarray:
    """Each line's distance to its nearest neighbour, Hz (inf for a single line)."""
    f = np.asarray(freq_hz, dtype=float)
    gaps = np.diff(f)
    if gaps.size == 0:
        return np.full(f.shape, np.inf)
    return np.minimum(np.r_[np.inf, gaps], np.r_[gaps, np.inf])


def common_lines(fa: np.ndarray, fb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(ka, kb)`` of the lines two records share, matched one to one, ascending.

    Each line of ``fa`` is paired with the nearest line of ``fb`` when they differ by at most
    :data:`LINE_MATCH_FRACTION` of the finer local spacing of the two, or by float32 rounding
    (:data:`FLOAT32_RTOL`), whichever is larger.
    """
    fa, fb = np.asarray(fa, dtype=float), np.asarray(fb, dtype=float)
    hi = np.clip(np.searchsorted(fb, fa), 0, fb.size - 1)
    lo = np.maximum(hi - 1, 0)
    k_b = np.where(np.abs(fb[lo] - fa) < np.abs(fb[hi] - fa), lo, hi)
    spacing = np.minimum(_line_spacing(fa), _line_spacing(fb)[k_b])
    tol = np.maximum(LINE_MATCH_FRACTION * np.where(np.isfinite(spacing), spacing, 0.0), FLOAT32_RTOL * fa)
    same = np.abs(fb[k_b] - fa) <= tol
    # The tolerance is below half of fa's spacing (on any grid float32 can hold apart), so no
    # two lines of fa reach one line of fb: the pairs are one to one.
    return np.flatnonzero(same), k_b[same]


def compare_frfs(a: FRFData, b: FRFData) -> FRFComparison:
    """Compare each FRF of ``a`` with the same (output, input) FRF of ``b``.

    Parameters
    ----------
    a, b : FRFData
        Accelerances ``H: (n_freq, n_out, n_in)`` of two tests of one structure (e.g. at two
        force levels); FRFs are matched by output and input label, lines by frequency
        (:func:`common_lines`: an adaptive stepped sine may measure other lines in another
        run, a file may hold its frequencies in float32). ``valid`` and ``H_var`` are used
        where present. An FRF with fewer than :data:`MIN_COMMON_LINES` valid values in
        common is not compared (None in ``curves``). The interface reactions
        ``H_reaction: (n_freq, n_react, n_in)`` (N/N, load cells on a test stand) that both
        records hold are compared in the same way, with ``H_reaction_var`` where present
        (a load cell off its calibration is a gain on its reactions, which the accelerances
        never show); a reaction value counts where any accelerance of its line and input
        is valid (a stepped sine blanks a line per input) and it is finite.

    Raises
    ------
    InputError
        No output and input label in common, fewer than :data:`MIN_COMMON_LINES` frequency
        lines in common, or no FRF with that many valid values in common (the common values
        blanked or non-finite in one of the two).
    """
    a = require_response(a, "first FRF data")
    b = require_response(b, "second FRF data")
    outputs = [o for o in a.outputs if o in b.outputs]
    inputs = [i for i in a.inputs if i in b.inputs]
    if not outputs or not inputs:
        raise InputError("the two FRF files share no output and input DOF labels")
    ka, kb = common_lines(a.freq_hz, b.freq_hz)
    if ka.size == 0:
        raise InputError("the two FRF files have no frequency line in common")
    if ka.size < MIN_COMMON_LINES:
        f0, f1 = a.freq_hz[ka[0]], a.freq_hz[ka[-1]]
        where = f"at {f0:g} Hz" if ka.size == 1 else f"{f0:g}-{f1:g} Hz"
        raise InputError(
            f"the two FRF files have only {ka.size} frequency line(s) in common ({where}; the "
            f"first has {a.n_freq} lines, the second {b.n_freq}): at least {MIN_COMMON_LINES} "
            "are needed to tell a gain from a shape difference")
    # Lines inside the band both records cover that found no partner: different grids there.
    f_lo, f_hi = max(a.freq_hz[0], b.freq_hz[0]), min(a.freq_hz[-1], b.freq_hz[-1])
    inside = max(int(np.count_nonzero((a.freq_hz >= f_lo) & (a.freq_hz <= f_hi))),
                 int(np.count_nonzero((b.freq_hz >= f_lo) & (b.freq_hz <= f_hi))))
    va, vb = a.valid_mask(), b.valid_mask()
    most_valid = 0

    def compare_one(ha, hb, ok, var_a, var_b) -> CurveComparison | None:
        nonlocal most_valid
        ok = ok & np.isfinite(ha) & np.isfinite(hb)
        n_ok = int(np.count_nonzero(ok))
        most_valid = max(most_valid, n_ok)
        if n_ok < MIN_COMMON_LINES:
            return None
        return compare_curves(ha[ok], hb[ok], None if var_a is None else var_a[ok],
                              None if var_b is None else var_b[ok])

    curves: list[list[CurveComparison | None]] = []
    for o in outputs:
        row = []
        ia, ib = a.outputs.index(o), b.outputs.index(o)
        for i in inputs:
            ja, jb = a.inputs.index(i), b.inputs.index(i)
            row.append(compare_one(a.H[ka, ia, ja], b.H[kb, ib, jb], va[ka, ia, ja] & vb[kb, ib, jb],
                                   None if a.H_var is None else a.H_var[ka, ia, ja],
                                   None if b.H_var is None else b.H_var[kb, ib, jb]))
        curves.append(row)
    in_b = set(_reaction_labels(b))
    reactions = [r for r in _reaction_labels(a) if r in in_b]
    # A reaction's line counts where any accelerance of that line and input is valid.
    line_a, line_b = va[ka].any(axis=1), vb[kb].any(axis=1)  # (n_common, n_in)
    reaction_curves: list[list[CurveComparison | None]] = []
    for r in reactions:
        ra, rb = a.reactions.index(r), b.reactions.index(r)
        row = []
        for i in inputs:
            ja, jb = a.inputs.index(i), b.inputs.index(i)
            row.append(compare_one(
                a.H_reaction[ka, ra, ja], b.H_reaction[kb, rb, jb], line_a[:, ja] & line_b[:, jb],
                None if a.H_reaction_var is None else a.H_reaction_var[ka, ra, ja],
                None if b.H_reaction_var is None else b.H_reaction_var[kb, rb, jb]))
        reaction_curves.append(row)
    if all(c is None for row in curves for c in row):
        # Otherwise "all 0 FRFs agree": nothing was compared, which is no agreement.
        if most_valid == 0:
            raise InputError(f"the two FRF files have no valid value in common ({len(ka)} common "
                             "frequency lines, every value blanked or non-finite in one of them)")
        raise InputError(f"no FRF has {MIN_COMMON_LINES} valid values in common in the two FRF files "
                         f"(at most {most_valid} of {len(ka)} common frequency lines; the others "
                         "blanked or non-finite in one of them)")
    return FRFComparison(a.freq_hz[ka], outputs, inputs, curves,
                         n_unmatched=max(inside - ka.size, 0), reactions=reactions,
                         reaction_curves=reaction_curves)


def _reaction_labels(frf: FRFData) -> list[str]:
    """The interface reactions a record holds (none without ``H_reaction``)."""
    return list(frf.reactions or []) if frf.H_reaction is not None else []
