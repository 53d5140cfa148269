"""FRF-level correlation: FRAC, an FRF gap measure, and the complex mode indicator function.

Arrays follow the FRF file: ``H`` (n_freq, n_out, n_in) complex; ``valid`` (same shape) bool,
False where a value is blanked and must not count.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import find_peaks

__all__ = [
    "CMIF_REPEATED_MIN_RATIO",
    "CMIF_WEAK_MIN_RATIO",
    "FRF_GAP_METRIC",
    "CmifModes",
    "cmif",
    "cmif_modes",
    "cmif_peaks",
    "cmif_shapes",
    "frf_assurance",
    "frf_gap",
    "frf_gap_db",
    "frf_gap_median",
    "refine_peak_frequencies",
]

#: Name of the measure returned by :func:`frf_gap` (written to JSON as ``frf_gap_metric``).
FRF_GAP_METRIC = "rms_log_ratio"


def _valid(H: np.ndarray, valid: np.ndarray | None) -> np.ndarray:
    ok = np.isfinite(H)
    return ok if valid is None else ok & np.asarray(valid, dtype=bool)


def _ratios(H_test: np.ndarray, H_model: np.ndarray, valid: np.ndarray | None) -> np.ndarray:
    """Model over test FRF at the valid values where both are finite and nonzero, flattened."""
    H = np.asarray(H_test)
    G = np.asarray(H_model)
    ok = _valid(H, valid) & np.isfinite(G) & (np.abs(H) > 0) & (np.abs(G) > 0)
    return G[ok] / H[ok]


def frf_assurance(H_test: np.ndarray, H_model: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Frequency response assurance criterion (FRAC) of each FRF, (n_out, n_in).

    ``FRAC_ij = |sum_k h_k^* g_k|^2 / (sum_k |h_k|^2 sum_k |g_k|^2)`` over the valid lines of
    FRF (i, j): the MAC of the two FRFs seen as vectors over frequency. 1 for identical
    shapes, insensitive to a constant complex factor (so it does not see a calibration error;
    :func:`frf_gap` does). NaN for an FRF with no valid line.
    """
    H = np.asarray(H_test)
    G = np.asarray(H_model)
    ok = _valid(H, valid) & np.isfinite(G)
    # Each FRF to a largest |value| of 1 first: FRAC, a ratio, does not depend on scale,
    # but the squares below overflow for a model in odd units (|H| near 1e200).
    h = _peak_scaled(np.where(ok, H, 0))
    g = _peak_scaled(np.where(ok, G, 0))
    num = np.abs(np.sum(h.conj() * g, axis=0)) ** 2
    den = np.sum(np.abs(h) ** 2, axis=0) * np.sum(np.abs(g) ** 2, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def _peak_scaled(h: np.ndarray) -> np.ndarray:
    """``h`` (n_freq, ...) with each curve divided by its largest |value| (zero curves kept)."""
    peak = np.max(np.abs(h), axis=0) if h.shape[0] else np.zeros(h.shape[1:])
    return h / np.where(peak > 0, peak, 1.0)


def frf_gap(H_test: np.ndarray, H_model: np.ndarray, valid: np.ndarray | None = None) -> float:
    """RMS complex log ratio of model to test FRFs over all valid values (dimensionless).

    ``gap = sqrt(mean |ln(g / h)|^2)``, ``ln(g/h) = ln|g/h| + j angle(g/h)``: the magnitude
    error in nepers (1 Np = 8.69 dB) and the phase error in radians, equally weighted. Unlike a
    relative error of ``H``, every line counts the same whether it sits on a resonance peak or
    in an antiresonance, as on the log-magnitude plots engineers read. 0 for identical FRFs;
    0.1 is about 10 % (0.87 dB) or 6 degrees everywhere. Values where either FRF is zero are
    skipped.
    """
    ratio = _ratios(H_test, H_model, valid)
    if not ratio.size:
        return float("nan")
    return float(np.sqrt(np.mean(np.log(np.abs(ratio)) ** 2 + np.angle(ratio) ** 2)))


def frf_gap_median(H_test: np.ndarray, H_model: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Median complex log ratio ``median |ln(g / h)|`` of model to test FRFs over the valid values.

    :func:`frf_gap`'s measure with the median in place of the RMS. Where a test value is
    mostly noise (an antiresonance or a far transfer FRF under the noise floor) its log ratio
    is large whatever the model, and a few such values decide the RMS; while fewer than half
    are, they do not move the median. Values where either FRF is zero are skipped.
    """
    ratio = _ratios(H_test, H_model, valid)
    if not ratio.size:
        return float("nan")
    return float(np.median(np.abs(np.log(ratio))))


def frf_gap_db(H_test: np.ndarray, H_model: np.ndarray, valid: np.ndarray | None = None) -> float:
    """RMS magnitude difference in dB, ``sqrt(mean (20 log10 |g/h|)^2)`` over valid values."""
    ratio = _ratios(H_test, H_model, valid)
    if not ratio.size:
        return float("nan")
    return float(np.sqrt(np.mean((20 * np.log10(np.abs(ratio))) ** 2)))


def cmif(H: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Complex mode indicator function: singular values of ``H(omega_k)``, (n_freq, min(n_out, n_in)).

    Descending at each line. Peaks of the first curve mark modes; a peak of the second at the
    same frequency marks a repeated or close pair. Blanked values are set to zero first
    (they lower the curve at that line rather than poison it with NaN).
    """
    Hc = np.where(_valid(np.asarray(H), valid), H, 0)
    return np.linalg.svd(Hc, compute_uv=False)


def cmif_peaks(freq_hz: np.ndarray, sv: np.ndarray, prominence_db: float = 3.0, curves: int = 1) -> np.ndarray:
    """Indices of the CMIF peaks (lines), ascending frequency.

    A peak is a local maximum of one of the first ``curves`` singular-value curves that
    stands ``prominence_db`` above its surroundings (scipy ``find_peaks`` prominence on the dB
    curve). Peaks of later curves within two lines of an earlier one are merged.

    The peak line is where the FRFs' response peaks, which is not the natural frequency. The
    FRFs here are accelerances: for one mode ``|H| ~ omega^2 / |omega_n^2 - omega^2 + 2 j zeta
    omega_n omega|``, largest at ``omega_n / sqrt(1 - 2 zeta^2)``, above the natural frequency
    by about ``zeta^2`` (0.04 % at 2 % damping, 1 % at 10 %: 10.10 Hz for a 10 Hz mode) and
    above the damped natural frequency ``omega_n sqrt(1 - zeta^2)`` by about ``1.5 zeta^2``.
    (A receptance would peak at ``omega_n sqrt(1 - 2 zeta^2)``, a mobility at ``omega_n``.)
    Neighbouring modes move it further, by their residual slope there.
    """
    freq_hz = np.asarray(freq_hz, dtype=float)
    found: list[int] = []
    for c in range(min(curves, sv.shape[1])):
        db = 20 * np.log10(np.maximum(sv[:, c], 1e-300))
        idx, _ = find_peaks(db, prominence=prominence_db)
        for k in idx:
            if all(abs(int(k) - j) > 2 for j in found):
                found.append(int(k))
    return np.asarray(sorted(found), dtype=int)


def refine_peak_frequencies(freq_hz: np.ndarray, curve: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Peak frequencies between the lines, Hz, (n_peaks,).

    A parabola through the dB values of the peak line and its two neighbours; its vertex
    locates a peak to a fraction of the line spacing (the raw line is off by up to half a
    spacing, several percent for a low mode on a linear grid).
    """
    f = np.asarray(freq_hz, dtype=float)
    db = 20 * np.log10(np.maximum(np.asarray(curve, dtype=float), 1e-300))
    out = []
    for k in np.asarray(lines, dtype=int):
        if k <= 0 or k >= f.size - 1:
            out.append(f[k])
            continue
        y0, y1, y2 = db[k - 1], db[k], db[k + 1]
        den = y0 - 2 * y1 + y2
        # Vertex offset in lines; |shift| <= 1/2 for a true local maximum.
        shift = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        shift = float(np.clip(shift, -0.5, 0.5))
        step = f[k + 1] - f[k] if shift > 0 else f[k] - f[k - 1]
        out.append(f[k] + shift * step)
    return np.asarray(out, dtype=float)


def cmif_shapes(H: np.ndarray, lines: np.ndarray, valid: np.ndarray | None = None,
                vectors: np.ndarray | None = None) -> np.ndarray:
    """Left singular vector of ``H`` at each given line: the mode-shape estimate, (n_out, n_lines).

    Near a resonance ``H ~ phi_r (L_r^T) / (j omega - lambda_r)`` is close to rank one, and its
    dominant left singular vector is the mode shape ``phi_r`` (complex, unit norm). At a
    repeated root the first ``k`` vectors span the modes' space (:func:`cmif_modes`).

    Parameters
    ----------
    vectors : (n_lines,) int, optional
        0-based singular vector taken at each line (its CMIF curve); default the first.
    """
    Hc = np.where(_valid(np.asarray(H), valid), H, 0)
    lines = np.asarray(lines, dtype=int)
    which = np.zeros(lines.size, dtype=int) if vectors is None else np.asarray(vectors, dtype=int)
    out = []
    for k, c in zip(lines, which):
        U, _, _ = np.linalg.svd(Hc[k])
        out.append(U[:, c])
    return np.array(out).T if out else np.zeros((Hc.shape[1], 0), dtype=complex)


#: A later CMIF curve that also peaks at a first-curve peak is taken for another mode at that
#: frequency when it stands at least this fraction of the first curve there (-10.5 dB). A
#: second mode at the same frequency peaks there at its own resonant level: equal to the first
#: curve for inputs that drive both alike (a symmetric tower), 0.45 with one input near the
#: base of the tower's y chain. At an isolated mode the later curve is what the other modes
#: and the noise leave, and it can peak there too: 0.20 of the first curve on a noise-free
#: random 6-DOF system with distinct modes at 1 % damping, and, at 3 % noise on each FRF
#: value, 2-4 such peaks per 180 modes above 0.1 (the bar was 0.1: a spurious test mode).
CMIF_REPEATED_MIN_RATIO = 0.3
#: Below the bar, a coinciding later-curve peak down to this fraction (-20 dB) is said in a
#: warning (:attr:`CmifModes.weak`): perhaps a second mode, driven weakly. (Down to 0.01 it
#: was said at 47-93 of 180 modes at 3 % noise.)
CMIF_WEAK_MIN_RATIO = 0.1


@dataclass
class CmifModes:
    """Modes found on the CMIF curves (:func:`cmif_modes`), ascending by peak, first curve first.

    Attributes
    ----------
    lines : (n_modes,) int
        Peak line of each mode on its own curve (for its frequency).
    curves : (n_modes,) int
        0-based CMIF curve of each mode (its singular vector).
    shape_lines : (n_modes,) int
        Line of its shape: for the modes of a group the first curve's peak line (a repeated
        root's modes are then the singular vectors of one SVD, orthonormal), else its own.
    groups : list of (n_g,) int arrays
        Modes (indices into the above) found at one peak on several curves that share a
        frequency (:func:`cmif_modes`).
    weak : list of (freq_hz, curve, ratio)
        Later-curve peaks at a first-curve peak below :data:`CMIF_REPEATED_MIN_RATIO` (and at
        :data:`CMIF_WEAK_MIN_RATIO` or more), not taken (curve 0-based).
    """

    lines: np.ndarray
    curves: np.ndarray
    shape_lines: np.ndarray
    groups: list = field(default_factory=list)
    weak: list = field(default_factory=list)


def cmif_modes(freq_hz: np.ndarray, sv: np.ndarray, prominence_db: float = 3.0,
               min_ratio: float = CMIF_REPEATED_MIN_RATIO) -> CmifModes:
    """Modes of the CMIF: each peak of the first curve, and under that peak one more mode for
    each later curve that also peaks there (within the first curve's half-power band, at least
    two lines either side; ``prominence_db`` as :func:`cmif_peaks`) at ``min_ratio`` or more
    of the first curve.

    The first curve alone misses one mode of every repeated root (a symmetric structure's
    pairs: three of six on a tower driven in x and y, though the second curve equalled the
    first at each of those peaks), and a mode hidden under a neighbour's peak by damping. A
    later curve is taken only while the curves before it were: the third needs the second.

    A later curve's mode shares the first one's frequency (a group) when its peak lies within
    a quarter of the half-power bandwidth of the first: the peaks of one root on two curves
    are apart only by what the other modes add there (0.012 Hz in a 0.37 Hz band on the
    tower), while two distinct modes under one peak are apart by much of it (0.51 Hz beside a
    0.92 Hz band, a 6-DOF chain at 5 % damping). The shapes of a group are the singular
    vectors at the first curve's peak line (one SVD: orthonormal); a mode of its own is taken
    at its own peak line.

    Parameters
    ----------
    freq_hz : (n_freq,); sv : (n_freq, n_curves) from :func:`cmif`
    """
    freq_hz = np.asarray(freq_hz, dtype=float)
    db = 20 * np.log10(np.maximum(sv, 1e-300))
    later = [find_peaks(db[:, c], prominence=prominence_db)[0] for c in range(sv.shape[1])]
    lines, curves, shape_lines, groups, weak = [], [], [], [], []
    used: set[tuple[int, int]] = set()
    for k in cmif_peaks(freq_hz, sv, prominence_db):
        members = [len(lines)]
        lines.append(int(k))
        curves.append(0)
        shape_lines.append(int(k))
        lo, hi = _half_power_band(db[:, 0], int(k))
        quarter = (freq_hz[hi] - freq_hz[lo]) / 4
        for c in range(1, sv.shape[1]):
            near = [int(j) for j in later[c] if lo <= j <= hi and (int(j), c) not in used]
            if not near:
                break
            kc = min(near, key=lambda j: abs(j - k))
            ratio = float(sv[kc, c] / sv[kc, 0]) if sv[kc, 0] > 0 else 0.0
            if ratio < min_ratio:
                if ratio >= CMIF_WEAK_MIN_RATIO:
                    weak.append((float(freq_hz[kc]), c, ratio))
                break
            used.add((kc, c))
            same = abs(freq_hz[kc] - freq_hz[k]) <= quarter
            if same:
                members.append(len(lines))
            lines.append(kc)
            curves.append(c)
            shape_lines.append(int(k) if same else kc)
        if len(members) > 1:
            groups.append(np.asarray(members, dtype=int))
    return CmifModes(np.asarray(lines, dtype=int), np.asarray(curves, dtype=int),
                     np.asarray(shape_lines, dtype=int), groups, weak)


def _half_power_band(db: np.ndarray, k: int) -> tuple[int, int]:
    """First and last line around peak line ``k`` of a dB curve within 3 dB of the peak, and at
    least two lines either side: the resonance a later curve's peak must lie in. (Two lines
    alone missed the top pair of a tower observed at 1+Y but not 1+X: the x and y curves
    peaked 3 lines, 0.01 Hz, apart, each pulled by its own residual.)"""
    lo = k
    while lo > 0 and db[lo - 1] >= db[k] - 3.0:
        lo -= 1
    hi = k
    while hi < db.size - 1 and db[hi + 1] >= db[k] - 3.0:
        hi += 1
    return max(min(lo, k - 2), 0), min(max(hi, k + 2), db.size - 1)
