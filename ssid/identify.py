"""``identify_mck``: the SSID pipeline from an FRF file's data to M, C, K and modal results.

Step 1 (``ssid.step1``) estimates ``M^-1 C, M^-1 K, M^-1 D`` ; step 2 (``ssid.step2``) solves the
state-space eigenproblem, fits the modal scale factors and rebuilds M, C, K. The default solver
``"ml"`` is ours (see ``docs/algorithm.md``): a weighted equation-error start followed by a
maximum-likelihood (output-error) refinement, with weights from the file's variances or
coherence when it has them and from the fit's own residuals when it does not.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from .errors import IdentificationError
from .fit_checks import (
    MISFIT_NOISE_RATIO,
    misfit_warning,
    modes_not_held_warning,
    relative_noise_level,
    unresolved_damping_warning,
)
from .frf import FRFData, accelerance_under_test_loads, require_frequency_dependence, require_response
from .jsonutil import to_jsonable
from .modal import (
    complex_modes,
    modal_damping_matrix,
    modal_phase_collinearity,
    physical_checks,
    real_modes,
    root_frequency_damping,
    unit_max_shapes,
)
from .noise import data_noise_weights, frf_noise_weights
from .reciprocity import reciprocity_check
from .rigid_body import choose_rigid_body_modes, definiteness_problems, semi_definite
from .solvers import power_of_two_near
from .step1 import (
    Step1Data,
    Step1Estimate,
    estimate_equation_error,
    predict_accelerance,
    reaction_transfer,
    step1_data,
)
from .step1_ml import step1_maximum_likelihood
from .step1_refine import output_error_cost
from .step2 import assemble_mck, state_space_modes
from .step2_refine import refine_mck_output_error

if TYPE_CHECKING:  # ssid.bands builds on this module
    from .bands import BandResult

__all__ = ["SSIDResult", "identify_mck", "identify_step1", "SOLVERS", "DAMPING_OPTIONS",
           "model_accelerance", "model_frf_errors", "model_output_error"]

SOLVERS = ("ml", "ls", "tls", "stls")
#: ``damping`` of :func:`identify_mck`: the damping matrix the delivered model carries.
DAMPING_OPTIONS = ("auto", "identified", "modal")
#: Largest relative disagreement between the copies of M in A_s, B_s (``mass_copies_mismatch``)
#: at which ``auto`` also tries step 1's damping on the written M (:func:`_choose_damping`).
STEP1_DAMPING_MISMATCH_MAX = 1e-3
#: The written model is refined by output error (:func:`_refine_written_model`) where its
#: weighted output error exceeds step 1's own by this factor (the statistic is a sum of about
#: as many squares as the data hold real values, thousands: a factor 2 is far outside its
#: spread), and it has at most REFINE_MAX_DOFS DOFs (the normal equations' work arrays grow as
#: n^4: 5 (n^2 x n^2) complex, 65 MB at 32 DOFs).
REFINE_COST_RATIO = 2.0
REFINE_MAX_DOFS = 32



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
        Which C was written: ``identified``, ``modal``, ``step1`` (:func:`_choose_damping`),
        or ``output_error`` when M, C and K were refined together to the data.
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
    return _prediction_errors(frf, model_accelerance(frf, M, C, K), weight)


def _prediction_errors(frf: FRFData, Hm: np.ndarray, weight: np.ndarray) -> tuple[float, float]:
    """(weighted output error, relative RMS error) of the accelerances ``Hm`` (any model's)
    against ``frf``, over the values with ``weight > 0``; inf when not finite."""
    valid = weight > 0
    r = np.where(valid, frf.H - Hm, 0.0)
    scale = np.linalg.norm(np.where(valid, frf.H, 0.0))
    c = float(np.sum((weight * np.abs(r)) ** 2))
    e = float(np.linalg.norm(r) / scale) if scale > 0 else np.inf
    return (c if np.isfinite(c) else np.inf), (e if np.isfinite(e) else np.inf)


@contextlib.contextmanager
def singular_fit_refused() -> Iterator[None]:
    """Turn a linear-algebra failure of an identification's fits into an IdentificationError.

    The data that pass the entry checks (:func:`ssid.frf.require_response`,
    :func:`ssid.frf.require_frequency_dependence`) can still leave a fit without a solution:
    a singular dynamic-stiffness matrix or normal matrix, an SVD that does not converge. That
    is a property of the data, not a bug, and its user needs a message rather than a
    traceback. Only ``numpy.linalg.LinAlgError`` is turned; any other exception is a bug and
    passes unchanged. Also usable as a decorator of an identification entry point.
    """
    try:
        yield
    except np.linalg.LinAlgError as exc:
        raise IdentificationError(
            f"the fit has no unique solution on these FRFs ({exc}): the response does not "
            "determine a model (outputs that read alike, or no resonance in the band?)") from exc


def _step2_weights(d: Step1Data, est: Step1Estimate) -> np.ndarray:
    """Per-value weights for Eq. 3.23: accelerance noise plus reaction noise seen through
    the model, ``var = sigma_h^2 + sum_m |(A^-1 D^_r)_im|^2 sigma_r,m^2`` (diagonal of the
    errors-in-variables covariance)."""
    if d.n_r == 0 or np.all(np.isinf(d.weight_r)):
        return d.weight
    G = np.abs(reaction_transfer(d, est)) ** 2  # (L, n, n_r)
    var_r = 1.0 / d.weight_r**2  # (L, n_r, n_in)
    with np.errstate(divide="ignore"):
        var_h = np.where(d.weight > 0, 1.0 / d.weight**2, np.inf)
    var = var_h + G @ var_r
    return np.where(np.isfinite(var), 1.0 / np.sqrt(var), 0.0)


def _step2(d: Step1Data, est: Step1Estimate, solver: str):
    """Eq. 3.12, the scale factors (Eq. 3.23) and M, C, K for one step-1 estimate.

    Roots below the lowest line that the data cannot tell from rigid-body modes become
    rigid-body modes (:mod:`ssid.rigid_body`). Returns (modes, M, C, K, assembly info,
    rigid-body info).
    """
    modes = state_space_modes(est.C_hat, est.K_hat)
    if solver == "ml":
        d.weight = _step2_weights(d, est)
    used, fit, rigid = choose_rigid_body_modes(d, est.C_hat, est.K_hat, modes)
    M, C, K, asm = assemble_mck(used, fit.u, fit.rigid_inv_mass)
    # Near-rigid roots are assembled as one block but are step 1's roots, reported as such.
    return (modes if used.near_rigid_kc is not None else used), M, C, K, asm, rigid


def _choose_damping(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray, zeta: np.ndarray,
                    damping: str, modal_possible: bool, w: np.ndarray,
                    C_step1: np.ndarray | None = None) -> tuple[np.ndarray, str, dict]:
    """The damping matrix the delivered model carries, and how it compares with the data.

    ``identified`` is the A_s partition of Eq. 3.15; ``modal`` the identified damping ratios
    on the real modes of (K, M) (section 6.2.3); ``step1`` (``auto`` only, when given) is step
    1's ``M^-1 C`` on the written M (``M C^``, made symmetric). On full-order chains with
    non-proportional dampers, one input and noise (2-8 DOFs, the report's or 1 % Gaussian),
    step 2's scale factors carried noise into the other two (the one kept 1.2-55 % off the
    true C); on five records of six ``M C^`` predicted the data better than both, 0.4-14 % off,
    and on the sixth (8 DOFs) the modal C stayed. It is offered only when it is a damping
    matrix (positive semi-definite): on one of the five (6 DOFs) it had a negative eigenvalue,
    and the modal C, 30 % off, is written instead. When the identified model is not one
    second-order system (a reduced-order model whose scale factors cannot make the three
    copies of M in A_s agree, ``mass_copies_mismatch``), the partition's C does not carry
    the roots' damping: on the payload's 10-DOF models, noise-free, its own modes were 39-457 %
    off in damping where the roots were within 2-15 %, and its FRFs 13-49 % off the data
    where the modal C gave 6-9 %. ``auto`` keeps whichever predicts the band's measurements
    better (:func:`model_output_error` with ``w``, the data's noise weights); a full-order
    model with non-proportional damping keeps the identified or the step-1 C, which (unlike
    the modal one) can represent it.

    Returns
    -------
    (C, the name of the one kept, {"weighted_output_error": {name: cost},
    "frf_relative_rms_error": {name: ||H - H_model|| / ||H|| over the valid values},
    "chosen": name})
    """
    if damping == "modal" and not modal_possible:
        raise IdentificationError("modal damping needs a positive-definite identified M")
    options = {"identified": C}
    if damping in ("auto", "modal") and modal_possible:
        options["modal"] = modal_damping_matrix(M, K, zeta)
    if damping == "auto" and C_step1 is not None:
        C1 = (C_step1 + C_step1.T) / 2
        # Offered only as a damping matrix (no motion gains energy): a new candidate must not
        # bring a non-physical C that the other two would not have.
        if semi_definite(C1):
            options["step1"] = C1
    if damping != "auto":
        options = {damping: options[damping]}
    cost, rel = {}, {}
    for name, Cx in options.items():
        cost[name], rel[name] = model_frf_errors(frf, M, Cx, K, w)
    # Equal to rounding (exact data, where the identified and the step-1 C are both the true
    # one, their FRFs within 1e-9 of each other): the first in the order above, so that a tie
    # does not flip with rounding.
    best = min(cost, key=cost.get)
    chosen = next(k for k in options if cost[k] <= cost[best] or rel[k] <= rel[best] + 1e-9)
    return options[chosen], chosen, {"weighted_output_error": cost,
                                     "frf_relative_rms_error": rel, "chosen": chosen}


def _rigid_body_note(n_rigid: int, rigid: dict) -> str:
    """What the result says about the rigid-body modes it holds (``rigid``: the info of
    :func:`ssid.rigid_body.choose_rigid_body_modes`)."""
    test = next(t for t in rigid["tests"] if t["n_rigid_body_modes"] == n_rigid)
    f_line = rigid["lowest_line_rad_per_s"] / (2 * np.pi)
    return (f"{n_rigid} rigid-body mode(s) (free-free structure): K is singular by design, its null space "
            f"the rigid-body shapes, and C is zero on them; the {2 * n_rigid} roots nearest 0 "
            f"(|lambda| <= {max(test['roots_abs_rad_per_s']):.3g} rad/s, below the lowest line at "
            f"{f_line:.4g} Hz) fit the data as well as rigid-body motion does, and are taken as such")


def _real_roots_warning(real_roots: np.ndarray, m: int, n: int, n_rigid: int, rigid: dict) -> str:
    """The warning for real roots; those below the lowest line that failed the rigid-body test
    are named as what they are: not rigid-body modes, by the data."""
    said = (f"{real_roots.size} real (non-oscillatory) root(s): the model has {m} oscillatory modes"
            f"{f' and {n_rigid} rigid-body mode(s)' if n_rigid else ''} for {n} DOFs")
    tests = rigid.get("tests", []) if rigid else []
    rejected = tests[-1] if tests and tests[-1]["n_rigid_body_modes"] > n_rigid else None
    if rejected is not None:
        return (f"{said}; the roots nearest 0 (|lambda| <= {max(rejected['roots_abs_rad_per_s']):.3g} rad/s, "
                "below the lowest line) fit the data significantly better than rigid-body modes "
                "would (a likelihood-ratio test), so K is not made singular there")
    return f"{said} (noise or too few modes in the band)"


def _undamped_modes(M: np.ndarray, K: np.ndarray, n_rigid: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Undamped frequencies of (K, M) in Hz, ascending, the first ``n_rigid`` set to 0 (K is
    singular by design there, and eig(K, M) round-off), and the mass-normalised real modes;
    NaN and None when M is not positive definite."""
    try:
        wu, phi = real_modes(M, K)
    except np.linalg.LinAlgError:
        return np.full(M.shape[0], np.nan), None
    undamped = wu / (2 * np.pi)
    undamped[np.argsort(np.abs(wu))[:n_rigid]] = 0.0
    return undamped, phi


def _refine_written_model(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray, w: np.ndarray, noise: float,
                          written_errors: tuple[float, float], d: Step1Data,
                          est: Step1Estimate) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict] | None:
    """The written model refined by output error (:mod:`ssid.step2_refine`), where step 2 lost
    what step 1 held, and what came of it.

    ``written_errors`` is (weighted output error with ``w``, relative FRF error) of the written
    model; ``d``, ``est`` are step 1's data and the estimate it was written from, whose own
    model's errors are taken only where the cheaper conditions hold (identification runs this
    on every ``ml`` fit, band selection on every candidate band). Tried where step 1's model
    reproduces the data to their noise (relative error within
    :data:`ssid.fit_checks.MISFIT_NOISE_RATIO` times ``noise``: the model's order suffices) and
    the written one does not: its relative error is above the noise and its weighted output
    error more than :data:`REFINE_COST_RATIO` times step 1's. A reduced-order fit, whose step 1
    cannot hold the band either, is left as it is: there the refinement bent its C to negative
    eigenvalues (5 of 14 DOFs, noise-free) and took minutes on the payload's 16-DOF records.
    So is a model of more than :data:`REFINE_MAX_DOFS` DOFs. The refined model is taken
    (``info["accepted"]``) when its weighted output error is lower and it is physical (M
    positive definite, K and C positive semi-definite), also where the written one was not: on
    the free payload at 0.1 % noise the written K was not semi-definite (M 27 times off the true
    one) and the refined model was physical, M and K within 6.3 % and 4.8 %. A refined model
    that is not physical is not taken, however much closer to the data: from a written model far
    off, it stays far off (the same payload at 0.26 % noise: 69 % FRF error refined to 7.5 %,
    its M still 80 times off). Returns None when not tried, else ``(M, C, K, info)``.
    """
    cost_start, frf_error = written_errors
    if M.shape[0] > REFINE_MAX_DOFS or frf_error <= noise:
        return None
    cost_step1, error_step1 = _prediction_errors(frf, predict_accelerance(d, est), w)
    if error_step1 > MISFIT_NOISE_RATIO * noise or cost_start <= REFINE_COST_RATIO * cost_step1:
        return None
    try:
        Mx, Cx, Kx, info = refine_mck_output_error(frf, M, C, K, w)
    except np.linalg.LinAlgError:
        return None
    cost, err = model_frf_errors(frf, Mx, Cx, Kx, w)
    physical = definiteness_problems(Mx, Kx) == 0 and semi_definite(Cx)
    info.update(cost_step1=cost_step1, frf_relative_rms_error_step1=error_step1,
                frf_relative_rms_error_start=frf_error, frf_relative_rms_error=err,
                accepted=bool(physical and cost < info["cost_start"]))
    return Mx, Cx, Kx, info


def _written_root_freq_hz(M: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Natural frequencies ``|lambda| / 2 pi`` of the written M, C, K's oscillatory roots (Hz,
    :func:`ssid.modal.complex_modes`), rigid-body modes (at 0) left out; empty when M is singular."""
    try:
        lam, _ = complex_modes(M, C, K)
    except np.linalg.LinAlgError:
        return np.zeros(0)
    return np.abs(lam) / (2 * np.pi)


def _hard_problems(modes, M: np.ndarray, K: np.ndarray) -> int:
    """How many ways a model is not physical: real roots, negative damping, M not positive
    definite, K not positive semi-definite (each counts once)."""
    m = modes.n_pairs
    _, zeta = root_frequency_damping(modes.lam[:m])
    return int(modes.lam.size > 2 * m) + int(np.any(zeta < 0)) + definiteness_problems(M, K)


# Largest |H| (valid values) inside which step 1 works on the data as they are. Outside, it works
# on H divided by the power of two nearest that largest value and scales M^-1 D back: the
# equation-error starts (the report's TLS) are not invariant to the scale of H beside the unit
# columns of D, and the starts' output errors (squared weighted residuals) left float64 at
# |H| ~ 1e-90, where band processing then found 14 of the 15 modes it finds at |H| ~ 1. Inside
# (1e-12 to 1e12: accelerances in any unit a lab uses) nothing is scaled, and results stay bit for
# bit what they were.
_STEP1_UNSCALED_LARGEST_H = (2.0**-40, 2.0**40)


def identify_step1(
    frf: FRFData, solver: str = "ml", candidates: dict | None = None, restart_real_roots: bool = True,
    low_line_starts: bool = True, search_above_band: bool = True, model_error_levels: bool = True,
) -> tuple[Step1Estimate, Step1Data, dict]:
    """Step 1 of SSID on all lines of ``frf``: ``M^-1 C, M^-1 K, M^-1 D`` (Eqs. 3.6-3.9).

    Data whose largest |H| lies far from 1 (outside 2^-40 to 2^40) are fitted divided by a power
    of two near it, exactly, and the estimates, the arranged data and the starts come back in
    the data's own scale (``_STEP1_UNSCALED_LARGEST_H``).

    Returns the estimate, the arranged data with the noise weights the solver used (step 2
    and band processing reuse them), and ``info`` (with a ``warnings`` list). With ``ml``,
    ``candidates`` (if given) receives the equation-error starts by name, and without
    reactions a model left with real roots is refined once more from oscillatory ones
    (:func:`ssid.step1_refine.oscillatory_start`) unless ``restart_real_roots`` is False.
    Band processing turns it off: its band fits have more roots than the band has modes, and
    their real roots are the computational ones its criteria reject; made oscillatory, they
    came out alike in neighbouring bands as false modes (a 1.53 Hz one beside the 1.29 Hz
    suspension mode on the 12-sensor payload, 1-1158 Hz, seed 4). ``low_line_starts`` adds
    the starts of :func:`ssid.step1.starts_above_low_lines` (``ml`` without reactions); band
    processing turns it off too, as its criteria were tuned on where its band fits stop, and
    so it does ``search_above_band`` (:func:`ssid.step1_refine.refine_roots_above_band`,
    ``ml`` without reactions), whose moved roots would be its band fits' computational ones.
    ``model_error_levels`` (``ml`` without reactions or file variances) takes an FRF's flat
    noise level from its differences where the fit's residuals show model error
    (:func:`ssid.step1_ml.step1_maximum_likelihood`, step 4); band processing turns it off:
    the error its band fits leave is that of modes narrower than a line at the low edge, and
    weighting it as noise kept the 1.29 Hz suspension mode of the 16-sensor payload (1-2300 Hz,
    200 Hz bands) within 0.06-0.22 % on seeds 1-5, against 0.17-1.26 % with the differences'
    levels.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    valid = frf.valid_mask()
    largest = float(np.max(np.abs(np.where(valid, np.nan_to_num(frf.H), 0.0)), initial=0.0))
    lo, hi = _STEP1_UNSCALED_LARGEST_H
    unit = power_of_two_near(largest)
    options = (restart_real_roots, low_line_starts, search_above_band, model_error_levels)
    if largest == 0.0 or lo <= largest <= hi or unit == 1.0:
        return _identify_step1(frf, solver, candidates, *options)
    scaled = replace(frf, H=frf.H / unit, H_var=None if frf.H_var is None else frf.H_var / unit**2)
    starts: dict | None = None if candidates is None else {}
    est, d, info = _identify_step1(scaled, solver, starts, *options)
    if candidates is not None:
        candidates.update({name: _step1_in_scale(e, unit) for name, e in starts.items()})
    # Weights are 1/sigma up to a common factor shared with the reactions' (not scaled).
    return _step1_in_scale(est, unit), replace(d, H=d.H * unit, weight=d.weight / unit), info


def _step1_in_scale(est: Step1Estimate, unit: float) -> Step1Estimate:
    """A step-1 estimate of H / ``unit`` for H itself: ``M^-1 C``, ``M^-1 K`` do not depend on the
    scale of H; ``M^-1 D_f``, ``M^-1 D_r`` scale with it (the accelerance is ``M^-1`` times forces)."""
    return Step1Estimate(est.C_hat, est.K_hat, est.Df_hat * unit, est.Dr_hat * unit)


def _identify_step1(
    frf: FRFData, solver: str, candidates: dict | None, restart_real_roots: bool, low_line_starts: bool,
    search_above_band: bool, model_error_levels: bool,
) -> tuple[Step1Estimate, Step1Data, dict]:
    """:func:`identify_step1` on data of any scale (the arguments are its own)."""
    valid = frf.valid_mask()
    weights = frf_noise_weights(frf)
    info: dict = {"n_lines": frf.n_freq, "n_values_blanked": int(np.count_nonzero(~valid))}
    if frf.n_react and weights is not None and solver == "ml":
        # Measured, not assumed: on the payload on its stand under the report's noise, the
        # search from the variances of the averages (H_var, H_reaction_var, as acquisition
        # writes them) ended at 190 times the true model's cost on one seed of four (22 %,
        # 7 modes missed) and 3-4 % on two others; from levels estimated from the data and
        # re-estimated at the fit, 0.5-2.1 % on seeds 1-7 (docs/algorithm.md, known limits).
        weights = None
        info["noise_levels"] = ("estimated from the data (the file's variances or coherence are "
                                "not used with reactions)")
    know_noise = weights is not None
    d = step1_data(frf, weights)
    warnings: list[str] = []
    if not d.col_ok.all():
        warnings.append(
            f"{int(np.count_nonzero(~d.col_ok))} (line, input) columns hold a blanked value and "
            "are left out of the equation-error fits"
        )
    if solver == "ml":
        est = step1_maximum_likelihood(d, valid, know_noise, info, candidates, restart_real_roots,
                                       low_line_starts, search_above_band, model_error_levels)
        if "ml_skipped" in info:
            warnings.append(info["ml_skipped"])
    else:
        est = estimate_equation_error(d, solver)
    info["warnings"] = warnings
    return est, d, info


@singular_fit_refused()
def identify_mck(
    frf: FRFData,
    *,
    solver: str = "ml",
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    damping: str = "auto",
    search_above_band: bool = True,
) -> SSIDResult:
    """Identify M, C, K of a substructure from accelerance FRFs with SSID.

    Parameters
    ----------
    frf : FRFData
        Accelerances ``H`` (n_freq, n_out, n_in) at all outputs for each input, optionally the
        interface reactions ``H_reaction`` (substructure on a test stand, section 3.1), a
        ``valid`` mask (blanked values are not used by any fit), ``H_var`` or ``coherence``.
    solver : {"ml", "ls", "tls", "stls"}
        Step-1 solver: ``ml`` (default) maximum-likelihood output-error refinement;
        ``ls``, ``tls``, ``stls`` the report's least squares, total least squares and scaled
        TLS on the equation-error form (Eqs. 3.7, 5.5, 5.14, section 5.1.3).
    f_min_hz, f_max_hz : float, optional
        Band of lines to use (default: all).
    damping : {"auto", "identified", "modal"}
        ``identified``: C from the A_s partition (Eq. 3.15); ``modal``: C rebuilt from the
        identified damping ratios and the real modes of (K, M) (section 6.2.3); ``auto``
        (default): of those two, and of step 1's ``M^-1 C`` on the written M (``step1``,
        where the fit is one second-order system, :func:`_choose_damping`), the one whose
        model predicts the band's measurements better (``info["damping_choice"]``;
        ``checks["frf_relative_rms_error"]`` is the delivered model's relative RMS FRF error).
        With ``auto`` and ``ml`` and no reactions, a written model that misses data step 1's
        own model holds is then refined by output error, M, C and K together, and written when
        physical (``damping`` ``"output_error"``, ``info["output_error_refinement"]``;
        :func:`_refine_written_model`).
    search_above_band : bool
        With ``ml`` and no reactions: after the refinement, search along the frequencies of
        the roots above the band (:func:`ssid.step1_refine.refine_roots_above_band`).

    Returns
    -------
    SSIDResult

    Raises
    ------
    IdentificationError
        Too few valid lines, FRFs that do not determine a model (the same at every line, of
        rank below the outputs; :func:`ssid.frf.require_frequency_dependence`), or a fit
        without a unique solution (:func:`singular_fit_refused`).
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    if damping not in DAMPING_OPTIONS:
        raise ValueError(f"unknown damping option {damping!r}; choose {', '.join(DAMPING_OPTIONS)}")
    require_response(frf)
    lo = float(frf.freq_hz[0]) if f_min_hz is None else float(f_min_hz)
    hi = float(frf.freq_hz[-1]) if f_max_hz is None else float(f_max_hz)
    data = frf.band(lo, hi)
    if data.n_freq == 0:
        raise IdentificationError(f"no frequency lines between {lo:g} and {hi:g} Hz")
    require_frequency_dependence(data)
    starts: dict = {}
    est, d, info = identify_step1(data, solver=solver, candidates=starts, search_above_band=search_above_band)
    warnings = list(info.pop("warnings"))
    warnings.extend(f"{p.describe()}; the symmetric M, C, K that SSID fits cannot hold both: check these "
                    "transducers before trusting the model" for p in reciprocity_check(data) if not p.reciprocal)

    step1_weight = d.weight
    modes, M, C, K, asm, rigid = _step2(d, est, solver)
    written_from = est  # the step-1 estimate whose roots the written model holds
    if solver == "ml" and _hard_problems(modes, M, K):
        # The refinement fits the data best but cannot hold what the data lack (e.g. a
        # reduced-order model with modes outside its reach); a start that is physical wins.
        tried = {"ml": (_hard_problems(modes, M, K), output_error_cost(d, est))}
        best = None
        for name, cand in starts.items():
            d.weight = step1_weight
            try:
                res = _step2(d, cand, solver)
            except (IdentificationError, np.linalg.LinAlgError):
                continue
            score = (_hard_problems(res[0], res[1], res[3]), output_error_cost(d, cand))
            tried[name] = score
            if score < tried["ml"] and (best is None or score < tried[best[0]]):
                best = (name, res, cand)
        info["candidates"] = {k: {"problems": v[0], "output_error": v[1]} for k, v in tried.items()}
        if best is not None:
            modes, M, C, K, asm, rigid = best[1]
            written_from = best[2]
            info["selected"] = best[0]
            warnings.append(
                f"the maximum-likelihood refinement gave a non-physical model; the "
                f"{best[0]} start, with fewer problems, is used instead"
            )
    info.update(asm)
    if rigid:
        info["rigid_body"] = rigid
    n_rigid = modes.n_rigid

    m = modes.n_pairs
    wn, zeta = root_frequency_damping(modes.lam[:m])
    shapes = unit_max_shapes(modes.theta_x[:, :m])
    mpc = modal_phase_collinearity(shapes)
    real_roots = modes.lam[2 * m :].real
    if n_rigid:
        warnings.append(_rigid_body_note(n_rigid, rigid))
    if real_roots.size:
        warnings.append(_real_roots_warning(real_roots, m, d.n, n_rigid, rigid))

    undamped, phi = _undamped_modes(M, K, n_rigid)
    w = data_noise_weights(data)  # one estimate for the damping choice and the fit checks
    # The modal C takes the ratios in the order of eig(K, M), whose first r are rigid (0 Hz).
    zeta_all = np.concatenate([np.zeros(n_rigid), zeta])
    # M C^ is the written model's C only where the written M is that of step 1's system: the
    # fit is one second-order system (the three copies of M agree, as on full-order chains
    # under noise: 8e-6 to 3e-4), not a reduced-order one (a 5-of-14-DOF model: 0.023, where
    # M C^ gave its first mode 4.7 % damping against the roots' 2.0 %).
    one_system = asm.get("mass_copies_mismatch", np.inf) < STEP1_DAMPING_MISMATCH_MAX
    C_step1 = M @ written_from.C_hat if one_system and not n_rigid else None
    requested = damping
    C, damping, info["damping_choice"] = _choose_damping(data, M, C, K, zeta_all, damping,
                                                         phi is not None, w, C_step1)
    frf_error = info["damping_choice"]["frf_relative_rms_error"][damping]
    noise = relative_noise_level(data, w)
    band = (float(data.freq_hz[0]), float(data.freq_hz[-1]))
    # Not with reactions: taken as exact loads, their noise biases the fit (the guide's record
    # on its stand: 0.228 % refined to 0.016 %, but the worst undamped mode of its M, K outside
    # the band went from 0.2 % to 2 % off the simulated truth, and in the band none came closer).
    if requested == "auto" and solver == "ml" and not n_rigid and not data.n_react:
        refined = _refine_written_model(data, M, C, K, w, noise,
                                        (info["damping_choice"]["weighted_output_error"][damping], frf_error),
                                        d, written_from)
        if refined is not None:
            info["output_error_refinement"] = refined[3]
            if refined[3]["accepted"]:
                M, C, K = refined[:3]
                frf_error = refined[3]["frf_relative_rms_error"]
                damping = "output_error"
                undamped, phi = _undamped_modes(M, K, n_rigid)
    checks, chk_warn = physical_checks(M, C, K, zeta)
    checks.update({k: v for k, v in asm.items()})
    checks["frf_relative_rms_error"] = frf_error
    warnings.extend(chk_warn)
    warnings.extend(said for said in (misfit_warning(checks["frf_relative_rms_error"], noise),
                                      unresolved_damping_warning(data.freq_hz, wn / (2 * np.pi), zeta, noise),
                                      # M not definite: the physical checks have said more already
                                      None if phi is None else
                                      modes_not_held_warning(wn / (2 * np.pi), _written_root_freq_hz(M, C, K),
                                                             band if damping == "output_error" else None))
                    if said)
    return SSIDResult(
        M=M,
        C=C,
        K=K,
        dofs=list(data.outputs),
        natural_freq_hz=wn / (2 * np.pi),
        damping_ratio=zeta,
        mpc=mpc,
        mode_shapes=shapes,
        undamped_freq_hz=undamped,
        real_mode_shapes=phi,
        real_roots=real_roots,
        n_rigid_body_modes=n_rigid,
        solver=solver,
        damping=damping,
        band_hz=band,
        checks=checks,
        warnings=warnings,
        info=info,
        # Step 2 re-weights d for Eq. 3.23: the data as step 1 weighted it.
        step1=(written_from, replace(d, weight=step1_weight)),
    )

