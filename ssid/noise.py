"""Noise models for simulated FRFs and the weights that undo them.

``add_report_noise`` is the report's ``addnoise`` (appendix A): per average, each FRF (one
output, one input, all lines) gets additive magnitude noise, uniform and zero-mean, scaled to
``mag_noise`` times the RMS magnitude of that FRF, and uniform phase noise of +-``phase_noise_rad``;
``n_avg`` such noisy copies are averaged. The report applies it to the response spectra and to
the forces; :func:`report_noise_frf` does both and forms H = A / F as its ``calvxf`` does.
"""

from __future__ import annotations

import numpy as np

from .frf import FRFData

__all__ = ["add_report_noise", "report_noise_frf", "frf_noise_weights"]


def add_report_noise(
    X: np.ndarray,
    rng: np.random.Generator,
    n_avg: int = 40,
    mag_noise: float = 0.02,
    phase_noise_rad: float = 2 * np.pi / 180,
) -> np.ndarray:
    """The report's ``addnoise`` applied along axis 0 (frequency) of ``X``.

    Parameters
    ----------
    X : (n_freq, ...) complex
        Noise-free spectra or FRFs; each trailing index is one record.
    rng : numpy Generator (seeded by the caller for reproducible tests).
    n_avg, mag_noise, phase_noise_rad
        Number of averages, magnitude noise as a fraction of the record's RMS magnitude, and
        phase noise half-width in radians (report: 40, 2 %, 2 degrees).

    Returns
    -------
    The average of ``n_avg`` noisy copies, same shape as ``X``.
    """
    X = np.asarray(X, dtype=complex)
    mag = np.abs(X)
    ph = np.angle(X)
    # The report normalises by norm/length for both signal and noise; the ratio is an RMS ratio.
    rms = np.sqrt(np.mean(mag**2, axis=0, keepdims=True))
    acc = np.zeros_like(X)
    for _ in range(n_avg):
        nm = 1 - 2 * rng.random(X.shape)
        nm -= nm.mean(axis=0, keepdims=True)
        nm *= mag_noise * rms / np.sqrt(np.mean(nm**2, axis=0, keepdims=True))
        npn = 1 - 2 * rng.random(X.shape)
        npn -= npn.mean(axis=0, keepdims=True)
        acc += (mag + nm) * np.exp(1j * (ph + phase_noise_rad * npn))
    return acc / n_avg


def report_noise_frf(frf: FRFData, seed: int, n_avg: int = 40, mag_noise: float = 0.02,
                     phase_noise_deg: float = 2.0) -> FRFData:
    """Noisy copy of ``frf`` under the report's noise model (response and force both noisy).

    Each input is taken as a unit force applied alone (the report's ``P``); its spectrum gets
    the same noise model, and ``H = A_noisy / F_noisy`` (and likewise the reactions).
    """
    rng = np.random.default_rng(seed)
    ph = np.deg2rad(phase_noise_deg)
    A = add_report_noise(frf.H, rng, n_avg, mag_noise, ph)
    F = add_report_noise(np.ones((frf.n_freq, frf.n_in), dtype=complex), rng, n_avg, mag_noise, ph)
    Hr = None
    if frf.H_reaction is not None:
        Hr = add_report_noise(frf.H_reaction, rng, n_avg, mag_noise, ph) / F[:, None, :]
    out = FRFData(
        freq_hz=frf.freq_hz.copy(),
        H=A / F[:, None, :],
        outputs=list(frf.outputs),
        inputs=list(frf.inputs),
        H_reaction=Hr,
        reactions=None if frf.reactions is None else list(frf.reactions),
        n_avg=n_avg,
    )
    return out


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
