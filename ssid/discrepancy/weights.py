"""Noise weights of measured FRFs: ``W = 1/sigma`` for every value, 0 where it is not valid.

The fit and the ranking need each value weighted by its noise. Three sources, best first:

1. ``H_var`` (variance of each value, e.g. from averages): used as it is.
2. ``coherence``: the random error of an H1 estimate, ``var ~ (1 - g^2)/g^2 |H|^2`` (Bendat and
   Piersol, as ``ssid.noise.frf_noise_weights``); its level, which needs the number of
   averages and a convention, is set per FRF from the data's roughness (below).
3. Neither: per FRF, relative noise plus a floor, ``var = alpha |H|^2 + beta``, both levels
   from roughness (below). Relative noise is what a coherence-limited estimate has; the floor
   is the sensor noise that swamps deep antiresonances and the low end of an accelerance, and
   without it those values would get weights orders of magnitude too large.

``|H|^2`` in 2. and 3. is the larger of the value's own and the mean of its two neighbours'
along frequency. A weight built from the value's own magnitude alone is correlated with its
noise -- values that noise happens to shrink get larger weights -- which biases every
weighted residual towards smaller ``|H|``, coherently over thousands of values: enough for a
spurious effect to "explain" null data and even survive cross-validation. The neighbours'
noise is independent of the value's, so a value shrunk by noise is weighted as its
neighbours are; the value's own magnitude still counts at a resonance peak sampled by few
lines, where the neighbours are much lower and would give the peak an outsized weight. Each
variance is also raised to at least the running median of its FRF over five lines (a one-line
dip is chance; a real antiresonance is wider).

Roughness: for independent noise of variance ``kappa s_k^2`` on line ``k``, the second
difference ``H[k-1] - 2 H[k] + H[k+1]`` has variance ``kappa (s_{k-1}^2 + 4 s_k^2 + s_{k+1}^2)``
while a smooth FRF adds little; so ``kappa`` is the median of the normalised squared second
differences divided by ``ln 2`` (the median of an exponential variable with mean ``kappa``).
The median ignores the few lines at sharp resonances where the FRF itself curves. The
two-level model needs more than a median can give: its relative level comes from the bins of
highest power, which are the lines near resonances, where a second difference holds much of
the FRF's own curvature, read as noise. It uses the fourth difference
``d4_k = H[k-2] - 4 H[k-1] + 6 H[k] - 4 H[k+1] + H[k+2]`` instead, which cancels curvature up
to cubic terms. For independent noise ``E |d4_k|^2 = sum c_i^2 var_{k+i}`` (``sum c_i^2 =
70``), that is ``alpha S_k + 70 beta`` with ``S_k = sum c_i^2 |H[k+i]|^2``.

The lines are sorted into bins by ``P'_k``, the mean ``|H|^2`` of lines ``k +- 3`` and
``k +- 4``, which leaves out the five lines of the difference on purpose: sorted by a power of
those same lines, an FRF below its floor (all noise) was sorted by its own noise, the low bins
got the small differences, and the fit read the noise as relative noise (the floor of the stand
cases' reactions came out a tenth of the truth). In each bin the median of ``|d4|^2 / ln 2``
(the median of an exponential variable is ``ln 2`` times its mean) should be ``alpha S + 70
beta``, ``S`` the bin's median ``S_k``; ``alpha, beta >= 0`` follow by non-negative least
squares in relative terms. But the lines of a bin have different ``S_k``, and the median of
exponential variables of different means is not ``ln 2`` times their median mean. So the fit
is repeated with each ``|d4_k|^2`` first scaled to its bin's typical size, by ``(alpha S + 70
beta) / (alpha S_k + 70 beta)`` at the first fit's levels (a second repeat changes nothing).
On the 8-DOF chain's FRFs with 2 % relative noise (``tests/test_discrepancy.py``), whose
resonances are a few lines wide, the mean ratio of true to estimated variance is 1.1-1.26
with the repeat, 1.2-1.35 without it, 1.06-1.26 with second differences. On the stand cases'
null data (``tests/test_stand_noise.py``, 1 % relative noise plus a floor) the accelerances'
variance comes out more than 5.1-6.2 times the truth at one line in ten (12-16 with second
differences), the reactions' more than 8.7-17 times (12-17), and the search names no effect
on any of its 12 seeds without stated variances (11 with second differences).
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
from scipy.optimize import nnls

from ..frf import FRFData

__all__ = ["neighbour_power", "noise_weights", "reaction_variance", "roughness_level", "two_level_variance"]

#: Bin edges (quantiles of S) of the two-level roughness fit: finer at the low end, where the
#: floor shows (antiresonances are few lines).
BIN_QUANTILES = np.array([0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
N_BINS = BIN_QUANTILES.size - 1
#: Coherence is clipped to [COHERENCE_FLOOR, 1] and 1 - g^2 to at least this.
COHERENCE_FLOOR = 1e-6


def neighbour_power(H: np.ndarray, valid: np.ndarray, offsets: tuple[int, ...] = (1,)) -> np.ndarray:
    """Mean of ``|H|^2`` at the valid lines ``k +- d``, ``d`` in ``offsets``, (n_freq, ...).

    NaN where none of those lines is valid. The default is the two neighbouring lines.
    """
    P = np.where(valid, np.abs(np.where(valid, H, 0)) ** 2, 0.0)
    v = valid.astype(float)
    s = np.zeros_like(P)
    n = np.zeros_like(P)
    for d in offsets:
        s[d:] += P[:-d]
        n[d:] += v[:-d]
        s[:-d] += P[d:]
        n[:-d] += v[d:]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.where(n > 0, n, 1.0), np.nan)


def _running_median(x: np.ndarray, width: int) -> np.ndarray:
    """Median over ``width`` consecutive lines (axis 0), NaN ignored; edges use what exists."""
    half = width // 2
    pad = np.full((x.shape[0] + 2 * half,) + x.shape[1:], np.nan)
    pad[half:half + x.shape[0]] = x
    stack = np.stack([pad[i:i + x.shape[0]] for i in range(width)])
    out = np.full(x.shape, np.nan)
    has = np.isfinite(stack).any(axis=0)
    out[has] = np.nanmedian(stack[:, has], axis=0)
    return out


def roughness_level(H: np.ndarray, s2: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Level ``kappa`` (n_out, n_in) with ``var(H[k]) = kappa s2[k]``, from second differences.

    Parameters
    ----------
    H : (n_freq, n_out, n_in) complex
    s2 : (n_freq, n_out, n_in) float > 0
        Shape of the variance along frequency.
    valid : (n_freq, n_out, n_in) bool

    Returns
    -------
    (n_out, n_in) float; NaN for an FRF with fewer than 3 consecutive valid lines.
    """
    out = np.full(H.shape[1:], np.nan)
    if H.shape[0] < 3:
        return out
    Hz = np.where(valid, H, 0)
    d2 = Hz[:-2] - 2 * Hz[1:-1] + Hz[2:]
    den = s2[:-2] + 4 * s2[1:-1] + s2[2:]
    ok = valid[:-2] & valid[1:-1] & valid[2:] & (den > 0)
    r = np.abs(d2) ** 2 / np.where(ok, den, 1.0)
    for idx in np.ndindex(*out.shape):
        sel = ok[(slice(None),) + idx]
        if sel.any():
            out[idx] = np.median(r[(slice(None),) + idx][sel]) / np.log(2.0)
    return out


#: Stencil of the two-level fit's fourth difference along frequency; its noise gain ``sum c^2`` is 70.
FOURTH_DIFFERENCE = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
#: Refits of the two-level levels with each line's difference scaled to its bin (module docstring).
TWO_LEVEL_REFITS = 1


def _two_levels(r: np.ndarray, s: np.ndarray, bins: list[np.ndarray], gain: float) -> tuple[float, float]:
    """``alpha, beta >= 0`` with ``E r_k = alpha s_k + gain beta`` from the bins' medians of ``r``."""
    sb = np.array([np.median(s[b]) for b in bins])
    rn, alpha, beta = r, 0.0, 0.0
    for refit in range(TWO_LEVEL_REFITS + 1):
        m = np.array([np.median(rn[b]) for b in bins]) / np.log(2.0)
        good = m > 0
        if not good.any():
            break
        A = np.column_stack([sb, np.full(sb.size, gain)])[good] / m[good, None]
        (alpha, beta), _ = nnls(A, np.ones(int(good.sum())))
        mu = alpha * s + gain * beta
        if refit == TWO_LEVEL_REFITS or not np.all(mu > 0):
            break
        rn = r.copy()
        for b, s_bin in zip(bins, sb):
            rn[b] = r[b] * (alpha * s_bin + gain * beta) / mu[b]
    return alpha, beta


def two_level_variance(H: np.ndarray, valid: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Variance ``alpha P + beta`` of each value, both levels per FRF from roughness.

    ``P`` (n_freq, n_out, n_in) is the power used for the relative part (the neighbours'
    ``|H|^2``). The roughness is the fourth difference along frequency (module docstring).
    Returns NaN for an FRF too short to estimate.
    """
    out = np.full(H.shape, np.nan)
    n, width = H.shape[0], FOURTH_DIFFERENCE.size
    if n < width:
        return out
    gain = float(np.sum(FOURTH_DIFFERENCE**2))
    Hz = np.where(valid, H, 0)
    Pz = np.where(np.isfinite(P), P, 0.0)
    span = [slice(i, n - width + 1 + i) for i in range(width)]  # lines k - 2 + i, k = 2 .. n - 3
    d4 = np.abs(sum(c * Hz[sl] for c, sl in zip(FOURTH_DIFFERENCE, span))) ** 2
    S = sum(c * c * np.abs(Hz[sl]) ** 2 for c, sl in zip(FOURTH_DIFFERENCE, span))
    Pf = neighbour_power(H, valid, offsets=(3, 4))[span[2]]
    ok = np.logical_and.reduce([valid[sl] for sl in span]) & np.isfinite(Pf)
    for idx in np.ndindex(*H.shape[1:]):
        sel = (slice(None),) + idx
        keep = ok[sel]
        if keep.sum() < 4 * N_BINS:
            continue
        order = np.argsort(Pf[sel][keep])
        edges = np.unique((BIN_QUANTILES * order.size).round().astype(int))
        bins = [order[a:b] for a, b in pairwise(edges) if b - a >= 5]
        alpha, beta = _two_levels(d4[sel][keep], S[sel][keep], bins, gain)
        if alpha > 0 or beta > 0:
            out[sel] = alpha * Pz[sel] + beta
    return out


def _variance_shape(coherence: np.ndarray | None, H: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, str, bool]:
    """Variance (n_freq, n_out, n_in), where it came from, and whether its level still needs setting."""
    P = np.fmax(neighbour_power(H, valid), np.abs(H) ** 2)
    if coherence is not None:
        g2 = np.clip(np.asarray(coherence, dtype=float), COHERENCE_FLOOR, 1.0)
        var = np.maximum(1 - g2, COHERENCE_FLOOR) / g2 * P
        source, needs_level = "coherence; level per FRF from roughness", True
    else:
        var = two_level_variance(H, valid, P)
        source, needs_level = "relative plus floor per FRF from roughness (no H_var or coherence)", False
    var = np.where(valid & np.isfinite(var) & (var > 0), var, np.nan)
    return np.fmax(var, _running_median(var, 5)), source, needs_level


def _filled(s2: np.ndarray) -> np.ndarray:
    """``s2`` with NaN replaced by its median and raised to 1e-12 of its largest value."""
    fill = float(np.nanmedian(s2)) if np.isfinite(s2).any() else 1.0
    s2 = np.where(np.isfinite(s2), s2, fill)
    return np.maximum(s2, 1e-12 * np.max(s2))


def reaction_variance(frf: FRFData, valid: np.ndarray) -> np.ndarray | None:
    """Variance of each measured reaction value, (n_freq, n_react, n_in), from its roughness.

    For a file with reactions but no ``H_reaction_var`` (a UFF exchange, an older run): the
    same two-level model as the accelerances' without coherence, relative plus floor per
    reaction FRF (module docstring). A line counts where any of its accelerances is valid.
    None without reactions, or when no reaction FRF has the lines to estimate it from (the
    accelerances' weights may take an arbitrary common level, the reactions' may not: it is
    their noise relative to the accelerances' that matters).
    """
    if frf.H_reaction is None:
        return None
    Hr = np.asarray(frf.H_reaction)
    vr = np.broadcast_to(valid.any(axis=1, keepdims=True), Hr.shape) & np.isfinite(Hr)
    var = _variance_shape(None, np.where(vr, Hr, 0), vr)[0]
    return _filled(var) if np.isfinite(var).any() else None


def noise_weights(frf: FRFData, valid: np.ndarray) -> tuple[np.ndarray, dict]:
    """Weights ``1/sigma`` (n_freq, n_out, n_in), 0 where not valid, and a description.

    The weights make the noise of every valid value about unit variance (complex:
    ``E |W (H - H_true)|^2 ~ 1``). With ``H_var`` the level is the file's; otherwise it is
    estimated per FRF from roughness (module docstring).

    Returns
    -------
    W : (n_freq, n_out, n_in) float
    info : dict
        ``source`` (text), ``roughness_ratio`` (median over FRFs of the roughness level of the
        weighted data: about 1 when the weights' level is right).
    """
    H = np.where(valid, frf.H, 0)
    s2, unusable = None, ""
    if frf.H_var is not None:
        s2 = np.where(valid, np.asarray(frf.H_var, dtype=float), np.nan)
        s2 = np.where(np.isfinite(s2) & (s2 > 0), s2, np.nan)
        source, needs_level = "H_var", False
        if not np.isfinite(s2).any():
            # All zero (or NaN): no variance was estimated. Filled, they would set every
            # weight to one arbitrary level (1 (m/s^2/N)^2) and the gaps in no unit at all.
            s2, unusable = None, "H_var holds no positive variance, not used; "
    if s2 is None:
        s2, source, needs_level = _variance_shape(frf.coherence, H, valid)
        source = unusable + source
    s2 = _filled(s2)
    kappa = np.ones(H.shape[1:])
    if needs_level:
        kappa = roughness_level(H, s2, valid)
        good = np.isfinite(kappa) & (kappa > 0)
        kappa = np.where(good, kappa, np.median(kappa[good]) if good.any() else 1.0)
    W = np.where(valid, 1.0 / np.sqrt(kappa[None] * s2), 0.0)
    check = roughness_level(H, 1.0 / np.where(valid, W, 1.0) ** 2, valid)
    ratio = float(np.nanmedian(check)) if np.isfinite(check).any() else float("nan")
    return W, {"source": source, "roughness_ratio": ratio}
