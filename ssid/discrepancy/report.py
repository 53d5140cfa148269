"""Where model and test disagree, in numbers: the gap by band and by FRF, paired modes, and the result.

The gap (``gap_metric = "rms_noise_normalised_residual"``) is the RMS over the valid values of
the difference between measured and model FRFs in units of the measurement noise,

    gap = sqrt( mean_valid |H_model - H_meas|^2 / sigma^2 ),

``sigma`` from the noise weights (``ssid.discrepancy.weights``). 1 means the model agrees with
the test within noise; 10 means the disagreement is ten times the noise. It is the quantity
the fit minimises, and, unlike a log ratio, it is not dominated by the values that noise
swamps anyway (deep antiresonances, the low end of an accelerance). The RMS complex log ratio
of ``ssidlab correlate`` (``rms_log_ratio``: 0.1 is about 10 % or 6 degrees everywhere) is
reported beside it for engineers who read FRF plots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from ssid.jsonutil import to_jsonable

from ..correlate import modal_assurance, pair_modes_by_mac, real_mode_from_complex
from ..correlate_frf import (
    FRF_GAP_METRIC,
    cmif,
    cmif_peaks,
    cmif_shapes,
    frf_gap,
    refine_peak_frequencies,
)
from ..frf import FRFData
from ..io import Model
from ..tam import normal_modes
from .effects import Effect

__all__ = [
    "GAP_METRIC",
    "LOG_GAP_METRIC",
    "DiscrepancyResult",
    "band_edges",
    "gap_by_band",
    "gap_by_frf",
    "noise_gap",
    "paired_modes",
]

GAP_METRIC = "rms_noise_normalised_residual"
LOG_GAP_METRIC = FRF_GAP_METRIC
#: Paired modes need at least this MAC.
MIN_MAC = 0.5


def band_edges(n_freq: int, n_bands: int) -> np.ndarray:
    """Line indices splitting ``n_freq`` lines into ``n_bands`` bands of (nearly) equal count, (n_bands + 1,)."""
    n_bands = max(1, min(n_bands, n_freq))
    return np.linspace(0, n_freq, n_bands + 1).round().astype(int)


def noise_gap(H_meas: np.ndarray, H_model: np.ndarray, W: np.ndarray) -> float:
    """``sqrt(mean |W (H_model - H_meas)|^2)`` over the values with ``W > 0``; NaN if none."""
    ok = W > 0
    if not ok.any():
        return float("nan")
    r = W[ok] * (H_model[ok] - H_meas[ok])
    return float(np.sqrt(np.mean(np.abs(r) ** 2)))


def gap_by_band(freq_hz: np.ndarray, H_meas: np.ndarray, H_models: dict[str, np.ndarray],
                W: np.ndarray, n_bands: int = 8) -> list[dict]:
    """Both gaps in each of ``n_bands`` bands (equal numbers of lines) for each model FRF set.

    Returns
    -------
    list of dicts ``{"f_lo_hz", "f_hi_hz", <name>: noise gap, <name>_log_ratio: log gap}``.
    """
    edges = band_edges(freq_hz.size, n_bands)
    valid = W > 0
    out = []
    for a, b in pairwise(edges):
        row = {"f_lo_hz": float(freq_hz[a]), "f_hi_hz": float(freq_hz[b - 1])}
        for name, Hm in H_models.items():
            row[name] = noise_gap(H_meas[a:b], Hm[a:b], W[a:b])
            row[f"{name}_log_ratio"] = frf_gap(H_meas[a:b], Hm[a:b], valid[a:b])
        out.append(row)
    return out


def gap_by_frf(H_meas: np.ndarray, H_model: np.ndarray, W: np.ndarray) -> np.ndarray:
    """The noise gap of each FRF (output, input), (n_out, n_in); NaN where an FRF has no valid value."""
    n_out, n_in = H_meas.shape[1:]
    out = np.full((n_out, n_in), np.nan)
    for i in range(n_out):
        for j in range(n_in):
            out[i, j] = noise_gap(H_meas[:, i, j], H_model[:, i, j], W[:, i, j])
    return out


def _model_modes(model: Model, out_idx: np.ndarray, f_max_hz: float) -> tuple[np.ndarray, np.ndarray]:
    lam, phi = normal_modes(model.M, model.K)
    f = np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi)
    keep = (f > 0) & (f <= 1.5 * f_max_hz)
    return f[keep], phi[np.ix_(out_idx, np.flatnonzero(keep))]


def _frf_modes(freq_hz: np.ndarray, H: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CMIF peaks of FRFs ``H`` (n_freq, n_out, n_in): frequencies and real shapes at the outputs."""
    sv = cmif(H, valid)
    peaks = cmif_peaks(freq_hz, sv)
    if peaks.size == 0:
        return np.zeros(0), np.zeros((H.shape[1], 0))
    return (refine_peak_frequencies(freq_hz, sv[:, 0], peaks),
            real_mode_from_complex(cmif_shapes(H, peaks, valid)))


def paired_modes(frf: FRFData, valid: np.ndarray, models: dict[str, Model],
                 out_idx: np.ndarray, predicted: dict[str, np.ndarray] | None = None) -> list[dict]:
    """Measured modes (CMIF peaks) paired by MAC with each model's normal modes at the outputs.

    With ``predicted`` (each model's accelerance under the test's loads, by name), a model's
    modes are the CMIF peaks of that prediction instead: a substructure model loaded by the
    measured reactions responds at the modes of the structure on its stand, not at its own.

    Returns
    -------
    One dict per measured mode: ``test_freq_hz`` and, for each model ``name``,
    ``<name>_freq_hz``, ``<name>_mac``, ``<name>_freq_error_percent`` (None when unpaired).
    """
    f_test, phi_test = _frf_modes(frf.freq_hz, frf.H, valid)
    if f_test.size == 0:
        return []
    rows = [{"test_freq_hz": float(f)} for f in f_test]
    for name, model in models.items():
        try:
            if predicted is not None:
                f_m, phi_m = _frf_modes(frf.freq_hz, predicted[name], valid)
            else:
                f_m, phi_m = _model_modes(model, out_idx, float(frf.freq_hz[-1]))
        except np.linalg.LinAlgError:
            f_m, phi_m = np.zeros(0), np.zeros((out_idx.size, 0))
        mac = modal_assurance(phi_test, phi_m) if f_m.size else np.zeros((f_test.size, 0))
        # MAC alone cannot tell neighbouring modes apart when few DOFs are measured: weight it
        # by frequency proximity so a pair is the same mode, not a look-alike far away.
        with np.errstate(divide="ignore", invalid="ignore"):
            near = np.exp(-np.abs(np.log(f_test[:, None] / f_m[None, :])) / 0.2) if f_m.size else mac
        by_test = {p.test: p for p in pair_modes_by_mac(mac * near, MIN_MAC * 0.5)}
        for t, row in enumerate(rows):
            p = by_test.get(t)
            ok = p is not None and mac[t, p.analysis] >= MIN_MAC
            fm = float(f_m[p.analysis]) if ok else None
            row[f"{name}_freq_hz"] = fm
            row[f"{name}_mac"] = float(mac[t, p.analysis]) if ok else None
            row[f"{name}_freq_error_percent"] = (
                100.0 * (row["test_freq_hz"] - fm) / fm if ok and fm else None)
    return rows




@dataclass
class DiscrepancyResult:
    """Outcome of :func:`ssid.discrepancy.find_discrepancy`.

    Attributes
    ----------
    effect : Effect
        The effect found (``Effect("none")`` when the data agree with the model within noise).
    effects : list of Effect
        Every effect added to the model (more than one only with ``max_effects > 1``).
    gap_before, gap_after : float
        ``rms_noise_normalised_residual`` between measured FRFs and the model's, without and
        with the effect(s) (module docstring).
    candidates : list of dict
        Ranked candidates (JSON form, the contract's keys first in each).
    updated_model : Model
        The nominal model with the effect(s) added (with the damping used, see ``info``).
    info : dict
        Everything else written to JSON (noise, damping, localisation, gaps by band and by
        FRF, paired modes, second round, timing).
    arrays : dict
        Arrays for the plots (freq_hz, H_meas, H_nominal, H_updated, valid, ...).
    """

    effect: Effect
    effects: list[Effect]
    gap_before: float
    gap_after: float
    candidates: list[dict]
    updated_model: Model
    info: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)
    gap_metric: str = GAP_METRIC

    @property
    def dofs(self) -> list[str]:
        return list(self.effect.dofs)

    @property
    def parameters(self) -> dict:
        return dict(self.effect.parameters)

    def to_json_dict(self) -> dict:
        """The result as plain JSON types, the contract's keys first; NaN/Inf become None."""
        return to_jsonable({
            "effect": self.effect.name,
            "dofs": list(self.effect.dofs),
            "parameters": dict(self.effect.parameters),
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "gap_metric": self.gap_metric,
            "candidates": self.candidates,
            "effects": [{"effect": e.name, "dofs": list(e.dofs), "parameters": dict(e.parameters)}
                        for e in self.effects],
            **self.info,
        })
