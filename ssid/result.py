"""The identified model (:class:`SSIDResult`) and how well a model's M, C, K predict FRF data.

Kept apart from :mod:`ssid.identify` so that the other routes to a model (band processing's
modal model, band selection) can build and score results without the SSID pipeline.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .frf import FRFData, accelerance_under_test_loads
from .jsonutil import to_jsonable

if TYPE_CHECKING:
    from .bands import BandResult
    from .step1 import Step1Data, Step1Estimate

__all__ = ["SSIDResult", "model_accelerance", "model_frf_errors", "model_output_error",
           "prediction_errors"]


@dataclass
class SSIDResult:
    """Identified substructure model and its modal summary.

    Attributes
    ----------
    M, C, K : (n, n)
        Mass, damping and stiffness over ``dofs`` (the FRF file's outputs, in order).
    dofs : list of str
    natural_freq_hz, damping_ratio : (m,)
        From the oscillatory state-space roots (Eqs. 5.18-5.19), ascending frequency.
    mpc : (m,)
        Modal phase collinearity of each mode (Eq. 5.20).
    mode_shapes : (n, m) complex
        Displacement partition of the state-space eigenvectors, largest entry 1.
    undamped_freq_hz : (n,)
        Square roots of the eigenvalues of (K, M), ascending (NaN if M is not definite).
    real_mode_shapes : (n, n) or None
        Mass-normalised real modes of (K, M).
    real_roots : (q,)
        Real (non-oscillatory) state-space roots, rad/s; a clean identification has none.
    solver : str
        The step-1 solver (``bands`` for a band-processed modal model).
    damping : str
        Which C was written: ``identified``, ``modal``, ``step1``
        (:func:`ssid.written_model.choose_damping`), or ``output_error`` when M, C and K were
        refined together to the data.
    n_rigid_body_modes : int
        Rigid-body modes of a free-free structure (:mod:`ssid.rigid_body`): K (and C) are
        singular in their directions by design, and the first ``n_rigid_body_modes`` values
        of ``undamped_freq_hz`` are 0. They are not among ``natural_freq_hz``.
    band_result : ssid.bands.BandResult or None
        For a band-processed modal model (``solver == "bands"``), the band-processing result
        it was assembled from: every root and its verdict (for
        :func:`ssid.bands.plot_band_roots`, or another choice of modes with
        :func:`ssid.modal_model.modal_model_from_bands`). Not written to JSON.
    step1 : tuple (Step1Estimate, Step1Data) or None
        Step 1's estimate the written model was assembled from (the refinement's, or the start
        with fewer problems that replaced it in step 2; before any output-error refinement of
        M, C, K) and the data, with the noise weights step 1 ended with:
        for diagnostics such as :func:`ssid.step1_refine.errors_in_variables_cost`. None for
        a band-processed model. Not written to JSON.
    """

    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    dofs: list[str]
    natural_freq_hz: np.ndarray
    damping_ratio: np.ndarray
    mpc: np.ndarray
    mode_shapes: np.ndarray
    undamped_freq_hz: np.ndarray
    real_mode_shapes: np.ndarray | None
    real_roots: np.ndarray
    solver: str
    damping: str
    band_hz: tuple[float, float]
    checks: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    n_rigid_body_modes: int = 0
    band_result: BandResult | None = field(default=None, repr=False)
    step1: tuple[Step1Estimate, Step1Data] | None = field(default=None, repr=False)

    def to_model(self):
        """The identified M, C, K as a :class:`ssid.io.Model` over ``dofs`` (what the model
        file, correlation and the discrepancy workflow take)."""
        from .io import Model  # local: the file layer must not load with the algorithm

        return Model(M=self.M, K=self.K, C=self.C, dofs=list(self.dofs))

    def to_json_dict(self) -> dict:
        """The result as plain JSON types (the contract's keys first); NaN/Inf become None."""
        return to_jsonable({
            "natural_freq_hz": [float(v) for v in self.natural_freq_hz],
            "damping_ratio": [float(v) for v in self.damping_ratio],
            "dofs": list(self.dofs),
            "mpc": [float(v) for v in self.mpc],
            "mode_shapes": {
                "dofs": list(self.dofs),
                "real": self.mode_shapes.real.tolist(),
                "imag": self.mode_shapes.imag.tolist(),
                "note": "complex displacement shapes, one column per mode, largest entry 1",
            },
            "undamped_freq_hz": [float(v) for v in self.undamped_freq_hz],
            "real_mode_shapes": None
            if self.real_mode_shapes is None
            else self.real_mode_shapes.tolist(),
            "real_roots_rad_per_s": [float(v) for v in self.real_roots],
            "n_rigid_body_modes": int(self.n_rigid_body_modes),
            "solver": self.solver,
            "damping_matrix": self.damping,
            "band_hz": [float(self.band_hz[0]), float(self.band_hz[1])],
            "checks": self.checks,
            "warnings": list(self.warnings),
            "info": self.info,
        })


def model_accelerance(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Accelerances of an identified model (over ``frf.outputs``) at the lines, outputs and
    inputs of ``frf``, measured reactions applied as the known forces they are (Eq. 3.6):
    :func:`ssid.frf.accelerance_under_test_loads`, (L, n, n_in) in (m/s^2)/N."""
    return accelerance_under_test_loads(M, C, K, list(frf.outputs), frf)


def model_output_error(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray,
                       weight: np.ndarray) -> float:
    """Weighted output error ``sum_kij w_kij^2 |H_kij - H^model_kij|^2`` of a model over the
    outputs of ``frf`` (:func:`model_accelerance`)."""
    return model_frf_errors(frf, M, C, K, weight)[0]


def model_frf_errors(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray,
                     weight: np.ndarray) -> tuple[float, float]:
    """(:func:`model_output_error`, relative RMS error ``||H - H_model|| / ||H||``), both over
    the values with ``weight > 0``; inf when not finite."""
    return prediction_errors(frf, model_accelerance(frf, M, C, K), weight)


def prediction_errors(frf: FRFData, Hm: np.ndarray, weight: np.ndarray) -> tuple[float, float]:
    """(weighted output error, relative RMS error) of the accelerances ``Hm`` (any model's)
    against ``frf``, over the values with ``weight > 0``; inf when not finite."""
    valid = weight > 0
    r = np.where(valid, frf.H - Hm, 0.0)
    scale = np.linalg.norm(np.where(valid, frf.H, 0.0))
    c = float(np.sum((weight * np.abs(r)) ** 2))
    e = float(np.linalg.norm(r) / scale) if scale > 0 else np.inf
    return (c if np.isfinite(c) else np.inf), (e if np.isfinite(e) else np.inf)
