"""Noise models for simulated FRFs and the weights that undo them.

``add_report_noise`` is the report's ``addnoise`` (appendix A): per average, each FRF (one
output, one input, all lines) gets additive magnitude noise, uniform and zero-mean, scaled to
``mag_noise`` times the RMS magnitude of that FRF, and uniform phase noise of +-``phase_noise_rad``;
``n_avg`` such noisy copies are averaged. The report applies it to the response spectra and to
the forces; :func:`report_noise_frf` does both and forms H = A / F as its ``calvxf`` does.
"""

from __future__ import annotations

import warnings

import numpy as np

from .frf import FRFData
from .solvers import power_of_two_near

__all__ = ["add_report_noise", "data_noise_weights", "difference_flat_levels", "fit_additive_proportional",
           "frf_noise_weights", "report_noise_frf", "roughness_weights", "variance_of_weight", "weight_of_variance"]

#: A flat level below this fraction of the differences' median-based level is taken as not
#: determined by them (:func:`difference_flat_levels`).
UNDETERMINED_FLAT = 1e-2


def add_report_noise(
    X: np.ndarray,
    rng: np.random.Generator,
    n_avg: int = 40,
    mag_noise: float = 0.02,
    phase_noise_rad: float = 2 * np.pi / 180,
    return_variance: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """The report's ``addnoise`` applied along axis 0 (frequency) of ``X``.

    Parameters
    ----------
    X : (n_freq, ...) complex
        Noise-free spectra or FRFs; each trailing index is one record.
    rng : numpy Generator (seeded by the caller for reproducible tests).
    n_avg, mag_noise, phase_noise_rad
        Number of averages, magnitude noise as a fraction of the record's RMS magnitude, and
        phase noise half-width in radians (report: 40, 2 %, 2 degrees).
    return_variance : bool
        Also return each value's variance of the average, estimated from the spread of the
        copies as an analyser does (``sum |x_i - mean|^2 / (n_avg (n_avg - 1))``); the noise
        drawn is the same either way.

    Returns
    -------
    The average of ``n_avg`` noisy copies, same shape as ``X`` (and its variance, real).
    """
    X = np.asarray(X, dtype=complex)
    mag = np.abs(X)
    ph = np.angle(X)
    # The report normalises by norm/length for both signal and noise; the ratio is an RMS ratio.
    rms = np.sqrt(np.mean(mag**2, axis=0, keepdims=True))
    acc = np.zeros_like(X)
    acc2 = np.zeros(X.shape)
    for _ in range(n_avg):
        nm = 1 - 2 * rng.random(X.shape)
        nm -= nm.mean(axis=0, keepdims=True)
        nm *= mag_noise * rms / np.sqrt(np.mean(nm**2, axis=0, keepdims=True))
        npn = 1 - 2 * rng.random(X.shape)
        npn -= npn.mean(axis=0, keepdims=True)
        x = (mag + nm) * np.exp(1j * (ph + phase_noise_rad * npn))
        acc += x
        acc2 += np.abs(x) ** 2
    mean = acc / n_avg
    if not return_variance:
        return mean
    spread = np.maximum(acc2 - n_avg * np.abs(mean) ** 2, 0.0) / max(n_avg - 1, 1)
    return mean, spread / n_avg


def report_noise_frf(frf: FRFData, seed: int, n_avg: int = 40, mag_noise: float = 0.02,
                     phase_noise_deg: float = 2.0, with_variance: bool = False) -> FRFData:
    """Noisy copy of ``frf`` under the report's noise model (response and force both noisy).

    Each input is taken as a unit force applied alone (the report's ``P``); its spectrum gets
    the same noise model, and ``H = A_noisy / F_noisy`` (and likewise the reactions). With
    ``with_variance`` the copy also holds ``H_var`` and ``H_reaction_var`` as an analyser
    estimates them from the spread of its averages, propagated to first order through the
    ratio, ``var H = (var A + |H|^2 var F) / |F|^2``; the noisy values are the same.
    """
    rng = np.random.default_rng(seed)
    ph = np.deg2rad(phase_noise_deg)
    A, vA = add_report_noise(frf.H, rng, n_avg, mag_noise, ph, return_variance=True)
    F, vF = add_report_noise(np.ones((frf.n_freq, frf.n_in), dtype=complex), rng, n_avg, mag_noise,
                             ph, return_variance=True)
    F2, vF = (np.abs(F) ** 2)[:, None, :], vF[:, None, :]
    H = A / F[:, None, :]
    Hr = var_r = None
    if frf.H_reaction is not None:
        R, vR = add_report_noise(frf.H_reaction, rng, n_avg, mag_noise, ph, return_variance=True)
        Hr = R / F[:, None, :]
        var_r = (vR + np.abs(Hr) ** 2 * vF) / F2
    return FRFData(
        freq_hz=frf.freq_hz.copy(),
        H=H,
        outputs=list(frf.outputs),
        inputs=list(frf.inputs),
        H_reaction=Hr,
        reactions=None if frf.reactions is None else list(frf.reactions),
        H_var=(vA + np.abs(H) ** 2 * vF) / F2 if with_variance else None,
        H_reaction_var=var_r if with_variance else None,
        n_avg=n_avg,
    )


def variance_of_weight(weight: np.ndarray, absent: float = 0.0) -> np.ndarray:
    """The variance ``1 / w^2`` a weight ``w = 1/sigma`` stands for, element-wise; ``absent``
    where ``w`` is 0 (a value the fit does not use: 0 to leave it out of a sum, inf to say
    it is not known)."""
    w = np.asarray(weight, dtype=float)
    return np.where(w > 0, 1.0 / np.where(w > 0, w, 1.0) ** 2, absent)


def weight_of_variance(var: np.ndarray) -> np.ndarray:
    """The weight ``1/sigma`` of a variance, element-wise; 0 where the variance is not positive
    (a value with no stated noise: not weighted)."""
    v = np.asarray(var, dtype=float)
    return np.where(v > 0, 1.0 / np.sqrt(np.where(v > 0, v, 1.0)), 0.0)


def frf_noise_weights(frf: FRFData, floor: float = 1e-6) -> np.ndarray | None:
    """Weights ``1/sigma`` (n_freq, n_out, n_in) from what the file knows of its noise, or None.

    From ``H_var`` when present; else from coherence, through the random error of an H1
    estimate, ``var|H| ~ (1 - g^2) / (2 n_avg g^2) |H|^2`` (Bendat and Piersol; the factor
    ``2 n_avg`` is common and irrelevant to a weighted fit). ``floor`` keeps a perfect coherence
    from giving an infinite weight. None when the file says nothing about its noise.
    """
    if frf.H_var is not None:
        var = np.asarray(frf.H_var, dtype=float)
    elif frf.coherence is not None:
        g2 = np.clip(np.asarray(frf.coherence, dtype=float), floor, 1.0)
        var = np.maximum(1 - g2, floor) / g2 * np.abs(frf.H) ** 2
    else:
        return None
    pos = var[np.isfinite(var) & (var > 0)]
    if pos.size == 0:
        return None
    var = np.where(np.isfinite(var) & (var > 0), var, np.median(pos))
    var = np.maximum(var, floor * np.median(pos))
    return 1.0 / np.sqrt(var)


def fit_additive_proportional(
    r2: np.ndarray,
    h2: np.ndarray,
    ok: np.ndarray,
    trim: float = 7.0,
    max_iter: int = 50,
) -> tuple[np.ndarray, np.ndarray]:
    """Fit the noise model ``var[k, i, j] = a2[i, j] + b2[j] |H[k, i, j]|^2`` to squared residuals.

    A measured FRF's noise is not one level: additive noise on the response spectrum is flat
    (``a2``, one level per FRF), while phase noise of the response and noise on the force
    spectrum are proportional to the FRF (``b2``, one level per input: the force noise is that
    input's, common to all outputs). The report's noise model has both (appendix A).

    Parameters
    ----------
    r2 : (L, n, n_in) float
        Squared magnitudes of residuals that hold noise only (e.g. ``|H - H_model|^2`` of a
        converged fit); for complex Gaussian noise ``r2 / var`` is exponential with mean 1.
    h2 : (L, n, n_in) float
        ``|H|^2`` the proportional part scales with (the model's, which carries no noise).
    ok : (L, n, n_in) bool
        Values to use (blanked values: False).
    trim : float
        Values with ``r2 > trim * var`` are left out of the next iteration: lines a model
        cannot follow (e.g. modes a reduced-order model lacks) must not set the noise level.
        The truncated exponential's mean, ``1 - t e^-t / (1 - e^-t)``, is corrected for.
    max_iter : int

    Returns
    -------
    a2 : (n, n_in) float, the flat variance of each FRF (units of ``r2``), > 0.
    b2 : (n_in,) float, the relative variance of the proportional part (>= 0, dimensionless).

    Notes
    -----
    Maximum likelihood for exponentially distributed ``r2`` with a mean linear in the
    parameters, by Fisher scoring (weighted least squares with weights ``1/var^2``); ``a2`` is
    eliminated per FRF, which leaves one scalar equation per input for ``b2``. ``a2`` is kept
    at least 1e-4 of the FRF's median-based flat level so that a value the model predicts near
    zero (an antiresonance) cannot receive an unbounded weight.
    """
    r2 = np.asarray(r2, dtype=float)
    h2 = np.asarray(h2, dtype=float)
    ok = np.asarray(ok, dtype=bool) & np.isfinite(r2) & np.isfinite(h2)
    # The weights 1/var^2 are fourth powers of |H|: they leave float64 from |H| ~ 1e77 or
    # 1e-77 on, inside the range the FRF reader accepts (1e-100 to 1e100). Squares relative
    # to a power of two near the largest |H|^2 stay within it; multiplying by a power of two
    # is exact, so on data that did not overflow the fit is bit for bit the same.
    scale = power_of_two_near(float(np.max(h2[ok])) if ok.any() else 1.0)
    r2, h2 = r2 / scale, h2 / scale
    flat = _median_flat_level(r2, ok)  # NaN for an FRF blanked everywhere: filled below
    pos = flat[np.isfinite(flat) & (flat > 0)]
    fill = np.median(pos) if pos.size else 1.0
    flat = np.where(np.isfinite(flat) & (flat > 0), flat, fill)
    a2 = flat.copy()
    b2 = np.zeros(r2.shape[2])
    for _ in range(max_iter):
        var = a2[None] + b2[None, None] * h2
        w = np.where(ok & (r2 < trim * var), 1.0 / var**2, 0.0)
        s_aa = w.sum(axis=0)  # (n, n_in)
        s_ab = (w * h2).sum(axis=0)
        s_bb = (w * h2**2).sum(axis=(0, 1))  # (n_in,)
        t_a = (w * r2).sum(axis=0)
        t_b = (w * h2 * r2).sum(axis=(0, 1))
        use = s_aa > 0
        q = np.where(use, s_ab / np.where(use, s_aa, 1.0), 0.0)
        schur = s_bb - (q * s_ab).sum(axis=0)
        rhs = t_b - (q * t_a).sum(axis=0)
        b2_new = np.where(schur > 0, np.maximum(rhs / np.where(schur > 0, schur, 1.0), 0.0), 0.0)
        a2_new = np.where(use, (t_a - s_ab * b2_new[None]) / np.where(use, s_aa, 1.0), flat)
        a2_new = np.maximum(a2_new, 1e-4 * flat)
        done = np.allclose(a2_new, a2, rtol=1e-6, atol=0) and np.allclose(
            b2_new, b2, rtol=1e-6, atol=1e-300)
        a2, b2 = a2_new, b2_new
        if done:
            break
    corr = _trimmed_mean_fraction(trim)
    return a2 / corr * scale, b2 / corr


def _median_flat_level(r2: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Median-based flat level ``median(r2) / ln 2`` of each FRF (n, n_in) over the values
    ``ok`` (the mean of an exponential variable from its median); NaN where there are none,
    without numpy's "All-NaN slice" warning reaching the engineer's terminal."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(np.where(ok, r2, np.nan), axis=0) / np.log(2.0)


def _trimmed_mean_fraction(trim: float) -> float:
    """Mean of a unit-mean exponential variable truncated at ``trim``, ``1 - t e^-t / (1 - e^-t)``:
    what trimming values above ``trim`` times their variance leaves of the mean."""
    return 1.0 - trim * np.exp(-trim) / (1.0 - np.exp(-trim))


def _differences(H: np.ndarray, valid: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``order``-th differences of ``H`` along axis 0 (frequency lines): (L - order, ...) values,
    whether each window holds valid values only, and the coefficients ``c`` (binomial, alternating
    sign; white noise of variance s^2 gives differences of variance ``sum c^2 s^2``)."""
    c = np.array([1.0])
    for _ in range(order):
        c = np.convolve(c, [1.0, -1.0])
    L = H.shape[0]
    window = range(order + 1)
    diff = sum(c[m] * H[m:L - order + m] for m in window)
    ok = np.logical_and.reduce([valid[m:L - order + m] for m in window])
    return diff, ok, c


def difference_flat_levels(
    H: np.ndarray,
    valid: np.ndarray,
    b2: np.ndarray,
    order: int = 4,
    trim: float = 7.0,
    max_iter: int = 50,
) -> tuple[np.ndarray, np.ndarray]:
    """Flat noise level of each FRF from its differences along frequency, with no model.

    The ``order``-th difference of an FRF along equally spaced lines annihilates polynomials
    of degree < ``order``; where the FRF is smooth on the scale of a few lines it holds noise
    only, of variance ``sum_m c_m^2 var[k + m]`` (``c``: the difference's coefficients). With
    the proportional level ``b2`` given, the flat level ``a2`` of the model
    ``var = a2 + b2 |H|^2`` (:func:`fit_additive_proportional`) is fitted to the squared
    differences by maximum likelihood, values above ``trim`` times the model trimmed (sharp
    resonances, where curvature survives the difference). Unlike a level fitted to a model's
    residuals, it does not count a reduced-order model's error as noise.

    Whether the differences hold noise or curvature, their lag-1 correlation tells: for white
    noise it is ``sum c_m c_(m+1) / sum c_m^2`` (-0.8 for order 4), while the differences of a
    noise-free FRF vary smoothly from line to line (near +1).

    Parameters
    ----------
    H : (L, n, n_in) complex FRFs on equally spaced lines.
    valid : (L, n, n_in) bool; a difference uses windows of valid values only.
    b2 : (n_in,) relative variance of the proportional part, e.g. a fit's (on the 10-DOF
        payload at 1-300 Hz under the report's noise, the residuals' ``b2`` was 1.0-1.2 times
        the truth where their flat levels were up to 3 times it).
    order : int
        4 annihilates cubics. Fitting ``b2`` too from 2nd differences put it at 2-3.5 times the
        truth on the payload records: resonance curvature survived them.
    trim, max_iter : as :func:`fit_additive_proportional`.

    Returns
    -------
    a2 : (n, n_in) float, the flat variance of each FRF; NaN where no window is valid or the
        proportional part leaves it undetermined (below :data:`UNDETERMINED_FLAT` times the
        median-based level of the differences).
    rho : (n, n_in) float, the lag-1 correlation of its normalised differences over the lines
        kept; NaN where undefined.
    """
    L = H.shape[0]
    shape = H.shape[1:]
    if L < order + 3:  # the correlation needs two differences
        return np.full(shape, np.nan), np.full(shape, np.nan)
    # As in fit_additive_proportional: H relative to a power of two near its largest value,
    # so that the weights 1/var^2 (fourth powers of |H|) stay within float64; exact scaling.
    scale = power_of_two_near(float(np.max(np.abs(np.where(valid, H, 0.0)))))
    H = H / scale
    diff, ok, c = _differences(H, valid, order)
    window = range(order + 1)
    gain = float(np.sum(c**2))
    # |H|^2 weighted as the difference weights each line's variance (H's own noise hardly
    # moves it).
    h2 = sum(c[m] ** 2 * np.abs(H[m:L - order + m]) ** 2 for m in window) / gain
    r2 = np.where(ok, np.abs(diff) ** 2 / gain, np.nan)
    prop = np.asarray(b2, dtype=float)[None, None] * h2
    start = _median_flat_level(r2, ok)  # (n, n_in); NaN: no valid window
    a2 = start.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(max_iter):
            var = a2[None] + prop
            keep = ok & (r2 < trim * var)
            w = np.where(keep, 1.0 / var**2, 0.0)
            a2_new = np.maximum((w * np.where(keep, r2 - prop, 0.0)).sum(axis=0) / w.sum(axis=0),
                                1e-4 * start)
            done = np.allclose(a2_new, a2, rtol=1e-6, atol=0, equal_nan=True)
            a2 = a2_new
            if done:
                break
        var = a2[None] + prop
        keep = ok & (r2 < trim * var)
        z = np.where(keep, diff / np.sqrt(gain * var), 0.0)
        both = keep[:-1] & keep[1:]
        num = np.where(both, np.real(np.conj(z[:-1]) * z[1:]), 0.0).sum(axis=0)
        den = np.sqrt(np.where(both, np.abs(z[:-1]) ** 2, 0.0).sum(axis=0)
                      * np.where(both, np.abs(z[1:]) ** 2, 0.0).sum(axis=0))
        rho = num / den
    corr = _trimmed_mean_fraction(trim)
    # Where the proportional part explains the differences, the flat level sinks toward the
    # fit's floor: there the differences do not determine it.
    a2 = np.where(a2 >= UNDETERMINED_FLAT * start, a2 / corr, np.nan)
    return a2 * scale * scale, rho


def silent_frfs(H: np.ndarray, valid: np.ndarray, rtol: float = 1e-12) -> np.ndarray:
    """Which FRFs (n, n_in) hold no signal: every valid value within ``rtol`` of the largest
    valid value of all (rounding), e.g. the cross FRFs of directions nothing couples in
    simulated data. ``H``, ``valid``: (n_freq, n, n_in)."""
    mag = np.where(valid, np.abs(H), 0.0)
    return mag.max(axis=0) <= rtol * mag.max()


def roughness_weights(H: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Noise weights ``1/sigma`` of each FRF from its roughness along frequency, with no model.

    With no variance or coherence in the file, the model of the noise is one level per FRF
    (output i, input j) over the band, as the additive magnitude noise of a measured spectrum
    has. For independent noise of variance s^2 on each line, the second difference
    ``H[k-1] - 2 H[k] + H[k+1]`` has variance 6 s^2 while a smooth FRF contributes little;
    the median over lines keeps the few lines at sharp resonances from setting the level.
    ``H`` and ``valid``: (n_freq, n_out, n_in); returns weights of that shape, 0 where blanked.
    """
    d2, ok, _ = _differences(H, valid, 2)
    r2 = np.where(ok, np.abs(d2) ** 2, np.nan)
    # An FRF with no three valid lines in a row (or a band of two lines) has no level:
    # NaN here, filled by _weights_from_levels, without numpy's "empty slice" warning
    # reaching the engineer's terminal.
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        s2 = np.nanmedian(r2, axis=0) / (6 * np.log(2.0))
    return _weights_from_levels(s2, valid)


def _weights_from_levels(s2: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Broadcast per-FRF variances (n, n_in) to weights (L, n, n_in); 0 where blanked."""
    pos = s2[np.isfinite(s2) & (s2 > 0)]
    fill = np.median(pos) if pos.size else 1.0
    s2 = np.where(np.isfinite(s2) & (s2 > 0), s2, fill)
    s2 = np.maximum(s2, 1e-12 * s2.max())
    return np.broadcast_to(1.0 / np.sqrt(s2), valid.shape) * valid


def data_noise_weights(frf: FRFData) -> np.ndarray:
    """Noise weights ``1/sigma`` (n_freq, n_out, n_in) of each value, from the data alone.

    From the file's variances or coherence (:func:`ssid.noise.frf_noise_weights`), else from
    each FRF's roughness; 0 where a value is blanked. The scale on which delivered models are
    compared with the measurements (:func:`ssid.result.model_output_error`).
    """
    valid = frf.valid_mask()
    w = frf_noise_weights(frf)
    if w is None:
        w = roughness_weights(np.where(valid, frf.H, 0.0).astype(complex), valid)
    return np.where(valid, w, 0.0)
