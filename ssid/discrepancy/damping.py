"""Damping of the measured modes, from the FRFs alone, for a model file without C.

Fitting one modal damping ratio of the *nominal* model to the data is biased when the data
hide an effect: peaks that do not line up are best matched by smearing them (a 5 % frequency
shift drives such a fit to its upper bound). So the ratio is first read off the measured
peaks, with no model at all, and refitted with the model only once an effect is in place.

Each measured mode (a CMIF peak) is fitted in a window around its peak by one pole pair
shared by every FRF, with a quadratic numerator per FRF for the mode's residue and the
neighbouring modes' influence (Levy's linearised common-denominator fit, refined by two
Sanathanan-Koerner iterations that remove its bias towards high damping):

    H_j(s) ~ (a_j0 + a_j1 s + a_j2 s^2) / (s^2 + b_1 s + b_0),   s = j omega / omega_peak

The numerators are eliminated by projection (they share the regressors ``1, s, s^2``), which
leaves a 2 x 2 system for ``b``; ``omega_r = sqrt(b_0) omega_peak``, ``zeta_r = b_1 / (2 sqrt(b_0))``.
"""

from __future__ import annotations

import numpy as np

from ..correlate_frf import cmif, cmif_peaks

__all__ = ["damping_from_data", "peak_damping_ratios"]

#: Half-width of the fitting window: this fraction of the peak frequency, at least MIN_LINES lines.
WINDOW_FRACTION = 0.04
MIN_LINES = 3
SK_ITERATIONS = 2


def _fit_pole(s: np.ndarray, H: np.ndarray) -> tuple[float, float] | None:
    """(omega_r / omega_peak, zeta) of one pole pair shared by the FRFs ``H`` (n_lines, n_frf)."""
    A = np.column_stack([np.ones_like(s), s, s**2])  # numerator regressors, (n_lines, 3)
    d_prev = np.ones(s.size)
    b = None
    for _ in range(1 + SK_ITERATIONS):
        wt = 1.0 / np.maximum(np.abs(d_prev), 1e-12)
        Aw = A * wt[:, None]
        Ar = np.vstack([Aw.real, Aw.imag])  # real coefficients: stack real and imaginary parts
        Q, _ = np.linalg.qr(Ar)
        rows_B, rows_y = [], []
        for j in range(H.shape[1]):
            h = H[:, j] * wt
            Bj = np.column_stack([-h, -h * s])  # columns for b0, b1
            yj = h * s**2
            Br = np.vstack([Bj.real, Bj.imag])
            yr = np.concatenate([yj.real, yj.imag])
            rows_B.append(Br - Q @ (Q.T @ Br))  # project out the numerator
            rows_y.append(yr - Q @ (Q.T @ yr))
        Bm = np.vstack(rows_B)
        ym = np.concatenate(rows_y)
        b, *_ = np.linalg.lstsq(Bm, ym, rcond=None)
        if not np.all(np.isfinite(b)) or b[0] <= 0:
            return None
        d_prev = s**2 + b[1] * s + b[0]
    wr = float(np.sqrt(b[0]))
    return wr, float(b[1] / (2 * wr))


def peak_damping_ratios(freq_hz: np.ndarray, H: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequency (Hz) and damping ratio of each measured mode, from the FRFs alone.

    Parameters
    ----------
    freq_hz : (n_freq,)
    H : (n_freq, n_out, n_in) complex
    valid : (n_freq, n_out, n_in) bool

    Returns
    -------
    f_hz, zeta : (n_modes,) arrays of the modes whose fit is plausible (pole inside its
    window, ``0 < zeta < 0.3``).
    """
    f = np.asarray(freq_hz, dtype=float)
    sv = cmif(H, valid)
    peaks = cmif_peaks(f, sv)
    Hflat = np.where(valid, H, np.nan).reshape(f.size, -1)
    out_f, out_z = [], []
    for k in peaks:
        half = max(WINDOW_FRACTION * f[k], MIN_LINES * (f[min(k + 1, f.size - 1)] - f[max(k - 1, 0)]) / 2)
        win = np.flatnonzero(np.abs(f - f[k]) <= half)
        if win.size < 2 * MIN_LINES:
            continue
        cols = np.flatnonzero(np.all(np.isfinite(Hflat[win]), axis=0))
        if cols.size == 0:
            continue
        h = Hflat[np.ix_(win, cols)]
        h = h / np.sqrt(np.mean(np.abs(h) ** 2, axis=0))  # every FRF counts alike
        fit = _fit_pole(1j * f[win] / f[k], h)
        if fit is None:
            continue
        wr, zeta = fit
        if abs(wr * f[k] - f[k]) <= half and 0 < zeta < 0.3:
            out_f.append(wr * f[k])
            out_z.append(zeta)
    return np.asarray(out_f), np.asarray(out_z)


def damping_from_data(freq_hz: np.ndarray, H: np.ndarray, valid: np.ndarray) -> float | None:
    """One damping ratio for all modes: the median of :func:`peak_damping_ratios`; None if no mode."""
    _, zeta = peak_damping_ratios(freq_hz, H, valid)
    return float(np.median(zeta)) if zeta.size else None
