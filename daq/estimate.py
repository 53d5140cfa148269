"""Signal estimators: harmonic (stepped sine) and spectral (random), vectorised over channels.

Stepped sine
    :class:`SineFit` fits ``x(t) = Re(X e^{i w t}) + Re(X2 e^{2iwt}) + Re(X3 e^{3iwt}) + a + b t``
    to every channel by least squares (one QR for all channels). The constant and the slope
    absorb DC offsets and the slow drift of AC/IEPE coupling; the harmonics keep distortion
    out of the fundamental and measure it. The residual gives the noise variance of each
    complex amplitude, ``E|X - X_true|^2 ~= 4 s^2 / N`` for residual variance ``s^2`` and
    ``N`` samples (white noise).

Random
    :func:`welch_spectra` accumulates the auto/cross spectral matrices of input forces and
    outputs (Welch: window, overlap); :func:`frf_from_spectra` turns them into H1, H2 or Hv,
    ordinary and multiple coherence, and the variance of each H value from the number of
    averages (Bendat and Piersol).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import get_window

__all__ = [
    "SineFit", "SineEstimate", "SpectralSums", "coarse_peaks", "frf_from_spectra", "frf_quality", "multi_input_frf",
    "resolution_bias", "spectra_of_blocks", "welch_blocks", "window_mu2",
]


@dataclass
class SineEstimate:
    """Harmonic estimate of one record.

    Attributes
    ----------
    X : (n_ch,) complex
        Complex amplitude (peak) of the fundamental, phase referred to sample ``first_index``
        of the line's time origin.
    var : (n_ch,) float
        E|X - X_true|^2 from the residual noise.
    thd : (n_ch,) float
        Harmonic distortion sqrt(|X2|^2 + |X3|^2) / |X|, over the harmonics inside the band
        (zero when none is).
    peak : (n_ch,) float
        Largest |sample| of the record (for the limits).
    n : int
        Samples used.
    """

    X: np.ndarray
    var: np.ndarray
    thd: np.ndarray
    peak: np.ndarray
    n: int


class SineFit:
    """Weighted least-squares fit at one frequency over windows of ``n`` samples (any start).

    The pseudo-inverse is computed once for local time; a window starting at absolute
    sample ``s`` is the same fit with the phases turned by ``e^{-i h w s/fs}``. Harmonics are
    fitted up to ``band_hz`` (the DAQ's passband edge; default 0.49 fs): above it the
    anti-alias filter attenuates them, and near Nyquist they alias and make the fit singular.
    """

    def __init__(self, freq_hz: float, fs_hz: float, n: int, harmonics: int = 3,
                 band_hz: float | None = None) -> None:
        self.freq_hz, self.fs_hz, self.n = float(freq_hz), float(fs_hz), int(n)
        t = np.arange(self.n) / self.fs_hz
        w = 2 * np.pi * self.freq_hz
        top = 0.49 * self.fs_hz if band_hz is None else min(float(band_hz), 0.49 * self.fs_hz)
        self.h = [h for h in range(1, harmonics + 1) if h * self.freq_hz <= top] or [1]
        cols = []
        for h in self.h:
            cols += [np.cos(h * w * t), np.sin(h * w * t)]
        tc = (t - t.mean()) / max(float(np.ptp(t)), 1e-12)
        cols += [np.ones_like(t), tc]
        A = np.stack(cols, axis=1)
        # Weighted by a Hann taper (kept away from zero at the ends): a transient at another
        # frequency - a mode still ringing after the last step - leaks far less into the
        # estimate than with flat weights, so settling can stop sooner; noise costs ~1.4x.
        w = 0.02 + np.hanning(self.n)
        sw = np.sqrt(w)
        self.pinv = np.linalg.pinv(A * sw[:, None]) * sw[None, :]  # (p, n)
        self.A = A
        self.dof = max(self.n - A.shape[1], 1)
        # Variance factor of the fundamental's complex amplitude per unit noise variance.
        g = self.pinv[:2] @ self.pinv[:2].T
        self.var_factor = float(g[0, 0] + g[1, 1])

    def fit(self, x: np.ndarray, start: int = 0, noise_var: np.ndarray | None = None) -> SineEstimate:
        """Fit the (n_ch, n) record ``x`` whose first sample is ``start`` samples after the
        line's time origin.

        ``noise_var`` (n_ch,): variance per sample of each channel's noise floor, when known
        (measured with the drive off). Otherwise the fit residual stands in for it - which
        also holds any transient still decaying, so it overstates the noise while settling.
        """
        x = np.asarray(x, dtype=float)
        coef = x @ self.pinv.T  # (n_ch, p)
        resid = x - coef @ self.A.T
        s2 = np.sum(resid**2, axis=1) / self.dof
        w = 2 * np.pi * self.freq_hz
        rot = {h: np.exp(-1j * h * w * start / self.fs_hz) for h in self.h}
        amps = [(coef[:, 2 * k] - 1j * coef[:, 2 * k + 1]) * rot[h] for k, h in enumerate(self.h)]
        X = amps[0]
        harm = np.sqrt(sum(np.abs(a) ** 2 for a in amps[1:])) if len(amps) > 1 else np.zeros(X.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            thd = np.where(np.abs(X) > 0, harm / np.abs(X), 0.0)
        if noise_var is not None:
            s2 = np.asarray(noise_var, float)
        return SineEstimate(X=X, var=s2 * self.var_factor, thd=thd, peak=np.max(np.abs(x), axis=1), n=self.n)


def frf_quality(H: np.ndarray, var: np.ndarray) -> np.ndarray:
    """Quality of each FRF value, ``|H|^2 / (|H|^2 + var H)`` (0 where undefined).

    The share of a value's expected square that is signal: 1 for an exact value, below 0.5
    when its standard deviation exceeds its size. It reads like a coherence and is held to
    ``[quality] min_coherence`` like one, for every excitation: a stepped-sine value has no
    coherence, and a multi-input random value with a good multiple coherence can still be
    poorly determined (shakers' forces alike at a line make ``Gxx`` nearly singular).
    """
    a2 = np.abs(H) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num(a2 / (a2 + var))


def multi_input_frf(XA: np.ndarray, XF: np.ndarray, varA: np.ndarray, varF: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``H = XA XF^-1`` from one record per excitation pattern, with first-order variances.

    Parameters
    ----------
    XA : (n_a, n_pat) complex
        Response (or reaction) amplitudes, one column per pattern.
    XF : (n_in, n_pat) complex
        Force amplitudes of every shaker in each pattern (n_pat = n_in). The phase reference
        of each column is arbitrary: it cancels in ``XA XF^-1``.
    varA, varF : same shapes, float
        Variances of the amplitudes.

    Returns
    -------
    H : (n_a, n_in) complex, var : (n_a, n_in) float
        ``dH = (dXA - H dXF) XF^-1``, so
        ``var H_ij = sum_p |XF^-1_pj|^2 (varA_ip + sum_l |H_il|^2 varF_lp)``.
    """
    Finv = np.linalg.inv(XF)
    H = XA @ Finv
    inner = varA + (np.abs(H) ** 2) @ varF  # (n_a, n_pat)
    var = inner @ (np.abs(Finv) ** 2)
    return H, var


# ---------------------------------------------------------------------------------------------
# Random excitation
# ---------------------------------------------------------------------------------------------


def welch_blocks(x: np.ndarray, block: int, overlap: float) -> list[np.ndarray]:
    """Overlapping blocks (n_ch, block) of the record ``x`` (n_ch, n)."""
    step = max(1, int(round(block * (1 - overlap))))
    return [x[:, s:s + block] for s in range(0, x.shape[1] - block + 1, step)]


def spectra_of_blocks(blocks: list[np.ndarray], window: str) -> np.ndarray:
    """One-sided spectra (n_blocks, n_ch, block//2+1) of windowed blocks (scaled like a
    linear spectrum; only ratios of spectra are used, so the scale cancels)."""
    if not blocks:
        return np.zeros((0, 0, 0), complex)
    n = blocks[0].shape[1]
    w = np.ones(n) if window == "rect" else get_window("hann", n, fftbins=True)
    arr = np.stack(blocks)  # (nb, n_ch, n)
    return np.fft.rfft(arr * w, axis=-1) / np.sum(w)


@dataclass
class SpectralSums:
    """Running sums of the spectral matrices over averages, per frequency bin.

    ``Gxx`` (n_f, n_in, n_in), ``Gyx`` (n_f, n_y, n_in), ``Gyy`` (n_f, n_y) (auto only);
    ``n_avg`` averages so far. Sums, not means: resuming adds more averages.
    """

    Gxx: np.ndarray
    Gyx: np.ndarray
    Gyy: np.ndarray
    Gyy_full_diag: np.ndarray | None = None
    n_avg: int = 0

    @classmethod
    def empty(cls, n_f: int, n_in: int, n_y: int) -> SpectralSums:
        return cls(np.zeros((n_f, n_in, n_in), complex), np.zeros((n_f, n_y, n_in), complex),
                   np.zeros((n_f, n_y)), None, 0)

    def add(self, Xf: np.ndarray, Xy: np.ndarray) -> None:
        """Add averages: ``Xf`` (n_avg, n_in, n_f) and ``Xy`` (n_avg, n_y, n_f) spectra."""
        self.Gxx += np.einsum("aif,ajf->fij", Xf, Xf.conj())
        self.Gyx += np.einsum("aif,ajf->fij", Xy, Xf.conj())
        self.Gyy += np.einsum("aif,aif->fi", Xy, Xy.conj()).real
        self.n_avg += Xf.shape[0]


def window_mu2(window: str, n: int) -> float:
    """Second moment of a window's power spectral kernel, in lines^2.

    The kernel ``P(k) = |W(k)|^2`` (``W`` the window's DTFT, ``k`` in lines = cycles per
    block) is computed on a grid 64 times finer than the lines, and
    ``mu2 = sum k^2 P / sum P`` is taken over its main lobe (between the first nulls either
    side of 0). Hann: 0.33 (analytically 1/3 over the whole kernel, whose sidelobes fall as
    k^-6 and hold 0.05 % of its power). The rectangular window's sidelobes fall as k^-2, so
    its whole-kernel moment is unbounded; the main lobe's (0.11) covers only part of its
    leakage (see :func:`frf_from_spectra`).

    Parameters
    ----------
    window : str
        ``"hann"`` or ``"rect"`` (as :func:`spectra_of_blocks`).
    n : int
        Block size in samples.
    """
    w = np.ones(n) if window == "rect" else get_window("hann", n, fftbins=True)
    ov = 64
    P = np.abs(np.fft.fft(w, n * ov)) ** 2
    k = np.fft.fftfreq(n * ov, 1.0 / n)  # lines
    half = n * ov // 2
    pos = P[:half]
    # First null (local minimum) on the positive side; the kernel is symmetric.
    i = int(np.argmax((pos[1:-1] <= pos[:-2]) & (pos[1:-1] <= pos[2:]))) + 1
    lobe = np.abs(k) <= k[i]
    return float(np.sum(k[lobe] ** 2 * P[lobe]) / np.sum(P[lobe]))


def frf_from_spectra(S: SpectralSums, estimator: str = "H1", mu2: float = 0.0) -> dict[str, np.ndarray]:
    """FRFs, coherences and variances from spectral sums, vectorised over bins and outputs.

    Estimators: ``H1 = Gyx Gxx^-1`` (noise on outputs), ``H2 = Gyy / Gxy`` (one input; noise
    on the input), ``Hv``: per output the total-least-squares solution, the eigenvector of the
    smallest eigenvalue of ``[[Gxx, Gxy], [Gyx, Gyy]]`` scaled by its auto-spectra (works for
    several inputs; see :func:`_hv` for what it estimates).

    ``var`` is E|H - H_true|^2 (complex), the random error plus the squared resolution bias
    (first order, Bendat and Piersol ch. 9; ``gamma^2`` the ordinary coherence, ``n`` the
    averages, ``n_in`` the inputs):

    * H1: ``Gnn [Gxx^-1]_jj / (n - n_in)``, ``Gnn = Gyy (1 - gamma_multi^2)`` (B&P 9.3);
      with one input ``|H1|^2 (1 - gamma^2) / (gamma^2 (n - 1))``.
    * H2 (one input): ``|H2|^2 (1 - gamma^2) / (gamma^2 (n - 1))``. ``1/H2 = Gxy / Gyy`` is
      the H1 estimate of x from y; under input noise m its residual is exactly m,
      uncorrelated with y, so ``var(1/H2) = Gmm / ((n - 1) Gyy)`` with
      ``Gmm = Gxx (1 - gamma^2)``, and ``var H2 = |H2|^4 var(1/H2)``. That is H1's formula
      divided by ``gamma^4`` (H1's was used before: 25 % low in standard deviation at a
      force SNR of 4.5).
    * Hv, one input: ``|Hv|^2 (1 - gamma^4) / (2 gamma^2 (n - 1))``. The scaled Hv is
      ``H1 / gamma`` (``|Hv| = sqrt(Gyy / Gxx)``, H1's phase): its log-magnitude error is
      half that of ``Gyy / Gxx``, ``(1 - gamma^2) / (2n)``, its phase error H1's,
      ``(1 - gamma^2) / (2 gamma^2 n)``. This is the scatter about what Hv estimates, which
      is biased unless the input's and output's noise-to-signal ratios are equal (see
      :func:`_hv`). With several inputs, H1's variance (not derived for Hv there).

    Resolution bias (``mu2`` > 0: continuous random, from :func:`window_mu2`): with a flat
    force spectrum, E[H1] is the true H convolved with the window's power kernel, so to first
    order ``b = (mu2 / 2) H''`` (H'' the curvature across lines, per line^2); from the
    expansions of ``E Gyy`` and ``E Gxy`` H2's is ``(mu2 / 2)(H'' + 2 |H'|^2 / H*)`` (zero at
    a single mode's peak), and Hv's (one input: the geometric mean of H1 and H2) half-way,
    ``(mu2 / 2)(H'' + |H'|^2 / H*)``. H' and H'' are the central first and second differences
    of the measured H across lines (the band's edge lines take their neighbour's). Their noise
    expectations for independent lines (``(v[k-1] + v[k+1]) / 4`` and
    ``v[k-1] + 4 v[k] + v[k+1]``, v the random variances) are subtracted from ``|H'|^2`` and
    from ``|b|^2 / (mu2/2)^2``, the results held at or above zero, so noise alone does not
    raise ``var`` much (on pure noise the expected stated ``|b|^2`` is ``0.37 (mu2/2)^2 6 v``,
    6 % of v with Hann). Measured on the QA's 14-DOF runs the second difference's noise was
    1.0-1.3 times that expectation. The cost: a bias below ~0.4 random standard deviations
    (Hann) is not stated, which would raise ``var`` by < 17 %. The measured H is already
    smoothed, so its curvature understates the true one at coarsely resolved peaks (by 10-50 %
    at 1.5-3 lines of half-power bandwidth, where :func:`coarse_peaks` warns). Periodic and
    burst random (``mu2 = 0``) are leakage-free.

    Parameters
    ----------
    S : SpectralSums
        Sums over ``S.n_avg`` averages; ``Gxx`` (n_f, n_in, n_in), ``Gyx`` (n_f, n_y, n_in),
        ``Gyy`` (n_f, n_y); consecutive lines of one block size.
    estimator : {"H1", "H2", "Hv"}
    mu2 : float
        Second moment of the analysis window's power kernel, lines^2 (0: no leakage).

    Returns
    -------
    dict
        ``H`` (n_f, n_y, n_in) complex; ``coherence`` (n_f, n_y, n_in): ordinary coherence
        with one input, multiple coherence (the same for every input) with several;
        ``ordinary`` (n_f, n_y, n_in); ``multiple`` (n_f, n_y); ``var`` (n_f, n_y, n_in):
        E|dH|^2 in H's units squared, ``var_random + |bias|^2``; ``var_random`` the random
        part; ``bias`` (n_f, n_y, n_in) complex, the stated resolution bias (0 if not
        significant).
    """
    Gxx, Gyx, Gyy = S.Gxx, S.Gyx, S.Gyy
    n_f, n_y, n_in = Gyx.shape
    # pinv: with fewer averages than inputs Gxx is singular (those values are not valid yet).
    Gxx_inv = np.linalg.pinv(Gxx, rcond=1e-12, hermitian=True)
    H1 = Gyx @ Gxx_inv
    diag_x = np.real(np.einsum("fii->fi", Gxx))
    with np.errstate(divide="ignore", invalid="ignore"):
        ordinary = np.abs(Gyx) ** 2 / (Gyy[:, :, None] * diag_x[:, None, :])
        multi = np.real(np.einsum("fyi,fij,fyj->fy", Gyx, Gxx_inv, Gyx.conj())) / Gyy
    ordinary = np.clip(np.nan_to_num(ordinary), 0.0, 1.0)
    multi = np.clip(np.nan_to_num(multi), 0.0, 1.0)
    coherence = ordinary if n_in == 1 else np.repeat(multi[:, :, None], n_in, axis=2)
    dof = max(S.n_avg - n_in, 1)
    Gnn = Gyy * (1 - multi)
    var = Gnn[:, :, None] * np.real(np.einsum("fjj->fj", Gxx_inv))[:, None, :] / dof
    g2 = ordinary
    if estimator == "H1":
        H, slope_terms = H1, 0.0
    elif estimator == "H2":
        if n_in != 1:
            raise ValueError("H2 needs a single input")
        with np.errstate(divide="ignore", invalid="ignore"):
            H = (Gyy / np.conj(Gyx[:, :, 0]))[:, :, None]
            var = np.where(g2 > 0, np.abs(H) ** 2 * (1 - g2) / (g2 * dof), np.inf)
        slope_terms = 2.0
    elif estimator == "Hv":
        H = _hv(Gxx, Gyx, Gyy)
        if n_in == 1:
            with np.errstate(divide="ignore", invalid="ignore"):
                var = np.where(g2 > 0, np.abs(H) ** 2 * (1 - g2**2) / (2 * g2 * dof), np.inf)
        slope_terms = 1.0
    else:
        raise ValueError(f"unknown estimator {estimator!r}")
    bias = resolution_bias(H, var, mu2, slope_terms)
    return {"H": H, "coherence": coherence, "ordinary": ordinary, "multiple": multi,
            "var": var + np.abs(bias) ** 2, "var_random": var, "bias": bias}


def resolution_bias(H: np.ndarray, var: np.ndarray, mu2: float, slope_terms: float = 0.0) -> np.ndarray:
    """First-order resolution (leakage) bias of spectral FRF estimates, from their curvature.

    ``b = (mu2 / 2)(H'' + c |H'|^2 / H*)`` with ``c = slope_terms`` (0 for H1, 2 for H2, 1
    for Hv; see :func:`frf_from_spectra`), H' and H'' the central first and second
    differences across lines; the noise of the differences is subtracted as stated in
    :func:`frf_from_spectra`.

    Parameters
    ----------
    H, var : (n_f, ...) complex, float
        Estimates on consecutive lines and their random variances E|dH|^2.
    mu2 : float
        Second moment of the window's power kernel, lines^2; 0 gives zero bias.

    Returns
    -------
    (n_f, ...) complex
        The bias (zero where it is not above the differences' noise, and with fewer than
        three lines).
    """
    b = np.zeros(H.shape, complex)
    if mu2 <= 0 or H.shape[0] < 3:
        return b
    Hf = np.nan_to_num(H)
    v = np.nan_to_num(var, posinf=0.0)  # an undefined value's neighbours state no bias from it
    c = 0.5 * mu2
    b[1:-1] = c * (Hf[2:] - 2 * Hf[1:-1] + Hf[:-2])
    noise = np.zeros(v.shape)
    noise[1:-1] = c**2 * (v[2:] + 4 * v[1:-1] + v[:-2])
    if slope_terms:
        d1sq = np.zeros(v.shape)
        d1sq[1:-1] = np.maximum(np.abs(Hf[2:] - Hf[:-2]) ** 2 / 4 - (v[2:] + v[:-2]) / 4, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            b = b + np.nan_to_num(c * slope_terms * d1sq / np.conj(Hf))
    # The edge lines take their neighbour's (the lines beyond the band are not summed).
    b[0], b[-1], noise[0], noise[-1] = b[1], b[-2], noise[1], noise[-2]
    # |b|^2 held to what lies above the noise expectation of the second difference.
    size2 = np.maximum(np.abs(b) ** 2 - noise, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(size2 > 0, b * np.sqrt(size2 / np.abs(b) ** 2), 0.0)


def coarse_peaks(H: np.ndarray, var: np.ndarray, max_lines: float = 3.5) -> np.ndarray:
    """Lines at a peak whose half-power bandwidth is under ``max_lines`` lines.

    At a local maximum of |H| across lines, a single mode ``H = A / (1 + j u)``,
    ``u = 2 (f - f_r) / B_r``, gives ``r = |H[k-1] - 2 H[k] + H[k+1]| / |H[k]| =
    2 s^2 / (1 + s^2)`` with ``s = 2 / B`` (B in lines), so ``B = 2 sqrt((2 - r) / r)``. A
    peak counts only where its value's standard deviation is under a third of |H| and its
    second difference is twice its noise's (``sqrt(v[k-1] + 4 v[k] + v[k+1])``). With Hann, a peak of 3.5 lines has a
    resolution bias of about 8 % at its top (B&P ``(B_e/B_r)^2 / 3``: 6 %); the bias stated
    in ``var`` is first order and understates it on narrower peaks.

    Parameters
    ----------
    H : (n_f, n_y, n_in) complex
    var : (n_f, n_y, n_in) float
        Random variances E|dH|^2.
    max_lines : float

    Returns
    -------
    (n_f,) bool
        True at a line where some output/input pair has such a peak.
    """
    out = np.zeros(H.shape[0], bool)
    if H.shape[0] < 3:
        return out
    Hf, v = np.nan_to_num(H), np.nan_to_num(var, posinf=np.inf)
    a = np.abs(Hf)
    mid = slice(1, -1)
    d2 = np.abs(Hf[2:] - 2 * Hf[mid] + Hf[:-2])
    # A peak of values known to a third of their size (quality 0.9), whose curvature is
    # twice its noise's standard deviation: noise alone does not make one.
    peak = (a[mid] >= a[2:]) & (a[mid] >= a[:-2]) & (a[mid] ** 2 > 9 * v[mid])
    significant = d2**2 > 4 * (v[2:] + 4 * v[mid] + v[:-2])
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.clip(d2 / a[mid], 1e-12, 2.0)
        lines = 2 * np.sqrt((2 - r) / r)
    out[mid] = np.any(peak & significant & (lines < max_lines), axis=(1, 2))
    return out


def _hv(Gxx: np.ndarray, Gyx: np.ndarray, Gyy: np.ndarray) -> np.ndarray:
    """Hv per output: the null direction of the (n_in+1) spectral matrix [x; y_i]."""
    n_f, n_y, n_in = Gyx.shape
    G = np.zeros((n_f, n_y, n_in + 1, n_in + 1), complex)
    G[:, :, :n_in, :n_in] = Gxx[:, None]
    G[:, :, n_in, :n_in] = Gyx
    G[:, :, :n_in, n_in] = np.conj(Gyx)
    G[:, :, n_in, n_in] = Gyy
    # Equalise the scales of forces and responses so that the TLS weighs them alike.
    s = np.sqrt(np.maximum(np.real(np.einsum("fyii->fyi", G)), 1e-300))
    Gs = G / (s[..., :, None] * s[..., None, :])
    _, v = np.linalg.eigh(Gs)
    v0 = v[..., :, 0] / s  # smallest eigenvalue's vector, back to physical scale
    # v0 = [a; b]: a^T x + b y = 0 -> y = -(a / b) x; H = conj of that in our convention.
    with np.errstate(divide="ignore", invalid="ignore"):
        Hv = -np.conj(v0[..., :n_in] / v0[..., n_in:n_in + 1])
    return Hv
