"""Step 2's written model: M, C, K assembled from a step-1 estimate, the damping matrix it
carries, and its refinement by output error where step 2 lost what step 1 held.

These are the choices :func:`ssid.identify.identify_mck` makes between step 1 and the result
(the report's step 2, Eqs. 3.12-3.26, and ours after it); they are kept here so that the
pipeline reads as its sequence of steps.
"""

from __future__ import annotations

import numpy as np

from .errors import IdentificationError
from .fit_checks import MISFIT_NOISE_RATIO
from .frf import FRFData
from .modal import complex_modes, modal_damping_matrix, real_modes, root_frequency_damping
from .result import model_frf_errors, prediction_errors
from .rigid_body import choose_rigid_body_modes, definiteness_problems, semi_definite
from .step1 import Step1Data, Step1Estimate, predict_accelerance, reaction_transfer
from .step2 import StateSpaceModes, assemble_mck, state_space_modes
from .step2_refine import refine_mck_output_error

__all__ = ["choose_damping", "refine_written_model", "step2_mck", "undamped_modes",
           "written_root_freq_hz", "hard_problems", "STEP1_DAMPING_MISMATCH_MAX",
           "REFINE_COST_RATIO", "REFINE_MAX_DOFS"]

#: Largest relative disagreement between the copies of M in A_s, B_s (``mass_copies_mismatch``)
#: at which ``auto`` also tries step 1's damping on the written M (:func:`choose_damping`).
STEP1_DAMPING_MISMATCH_MAX = 1e-3
#: The written model is refined by output error (:func:`refine_written_model`) where its
#: weighted output error exceeds step 1's own by this factor (the statistic is a sum of about
#: as many squares as the data hold real values, thousands: a factor 2 is far outside its
#: spread), and it has at most REFINE_MAX_DOFS DOFs (the normal equations' work arrays grow as
#: n^4: 5 (n^2 x n^2) complex, 65 MB at 32 DOFs).
REFINE_COST_RATIO = 2.0
REFINE_MAX_DOFS = 32


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


def step2_mck(d: Step1Data, est: Step1Estimate,
              solver: str) -> tuple[StateSpaceModes, np.ndarray, np.ndarray, np.ndarray, dict, dict]:
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


def choose_damping(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray, zeta: np.ndarray,
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


def undamped_modes(M: np.ndarray, K: np.ndarray, n_rigid: int) -> tuple[np.ndarray, np.ndarray | None]:
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


def refine_written_model(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray, w: np.ndarray, noise: float,
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
    cost_step1, error_step1 = prediction_errors(frf, predict_accelerance(d, est), w)
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


def written_root_freq_hz(M: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Natural frequencies ``|lambda| / 2 pi`` of the written M, C, K's oscillatory roots (Hz,
    :func:`ssid.modal.complex_modes`), rigid-body modes (at 0) left out; empty when M is singular."""
    try:
        lam, _ = complex_modes(M, C, K)
    except np.linalg.LinAlgError:
        return np.zeros(0)
    return np.abs(lam) / (2 * np.pi)


def hard_problems(modes: StateSpaceModes, M: np.ndarray, K: np.ndarray) -> int:
    """How many ways a model is not physical: real roots, negative damping, M not positive
    definite, K not positive semi-definite (each counts once)."""
    m = modes.n_pairs
    _, zeta = root_frequency_damping(modes.lam[:m])
    return int(modes.lam.size > 2 * m) + int(np.any(zeta < 0)) + definiteness_problems(M, K)
