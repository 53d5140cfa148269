"""M, C, K fitted in physical coordinates with the measured reactions as known loads.

Step 1 fits ``M^-1 D_r`` freely; where a reaction is, over the band, nearly a spring and a
dashpot on its own DOF's motion (a soft, damped stand), that column is nearly a combination
of ``M^-1 C`` and ``M^-1 K`` there and the data do not fix it
(:mod:`ssid.step1_reaction_spread`); step 2 then takes ``D_r`` as known and the error lands
in M, C, K. In physical coordinates, ``(K + i w C - w^2 M) x_j = e_j + D_r r_j`` with ``D_r``
known (unit gain at the reaction DOFs) has no such freedom. This module fits that form:
an equation-error start (linear in M, C, K, reweighted by the current model as in
Sanathanan-Koerner iterations) then the output error with the reactions' noise seen through
the model (errors in variables, :func:`eiv_weights`) and :func:`ssid.step2_refine.refine_mck_output_error`.
"""

from __future__ import annotations

import numpy as np

from .frf import FRFData
from .noise import variance_of_weight
from .result import model_frf_errors
from .rigid_body import definiteness_problems, semi_definite
from .step2_refine import loads_on_outputs, refine_mck_output_error

__all__ = ["equation_error_mck", "eiv_weights", "fit_mck_with_reactions", "refit_where_reactions_undetermined"]


def _unknown_columns(x: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Columns (L, n, n_in, 3P) of the equation error ``Z x`` in the upper triangles of M, C, K."""
    L, n, n_in = x.shape
    i, j = np.triu_indices(n)
    P = i.size
    cols = np.zeros((L, n, n_in, P), dtype=complex)
    p = np.arange(P)
    # (E_ij + E_ji) x: row i gets x_j, row j gets x_i (once on the diagonal)
    cols[:, i, :, p] += x[:, j, :].transpose(1, 0, 2)
    off = i != j
    cols[:, j[off], :, p[off]] += x[:, i[off], :].transpose(1, 0, 2)
    f = (-(omega**2), 1j * omega, np.ones_like(omega))
    return np.concatenate([cols * fm[:, None, None, None] for fm in f], axis=3)


def _variances(frf: FRFData, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Variance of each accelerance (inf where ``weight`` is 0) and of each reaction (or None)."""
    var_h = variance_of_weight(weight, absent=np.inf)
    var_r = None if frf.H_reaction_var is None else np.asarray(frf.H_reaction_var, float)
    return var_h, var_r


def equation_error_mck(frf: FRFData, weight: np.ndarray, start: tuple | None = None,
                       iterations: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Symmetric M, C, K minimising the weighted equation error ``Z x_j - e_j - D_r r_j``.

    ``x_j = -h_j / w^2``. The error's variance is ``sum_k |Z_ik|^2 var(x_k) + var(r_i)``; it
    depends on Z, so the fit is repeated ``iterations`` times with the previous Z (the first
    with ``start``'s, or, without one, equal weights on the acceleration form ``-Z x / w^2``).
    Values with weight 0 (blanked) leave their (line, input) out.
    """
    n = frf.n_out
    omega = frf.omega
    var_h, _ = _variances(frf, weight)
    ok = np.all(np.isfinite(var_h), axis=1)  # (L, n_in): a column with a blanked value is left out
    x = np.where(np.isfinite(var_h), -np.nan_to_num(frf.H) / omega[:, None, None] ** 2, 0.0)
    var_x = np.where(np.isfinite(var_h), var_h, 0.0) / omega[:, None, None] ** 4
    F, var_F = loads_on_outputs(frf)
    var_F = np.zeros(F.shape) if var_F is None else var_F
    A = _unknown_columns(x, omega)  # (L, n, n_in, 3P)
    i, j = np.triu_indices(n)
    P = i.size
    scale = np.ones(3 * P)
    M = C = K = None
    if start is not None:
        M, C, K = start
    for it in range(iterations + 1):
        if M is None:
            s = np.ones((frf.n_freq, n, frf.n_in)) / omega[:, None, None] ** 2
        else:
            Z = K[None] + 1j * omega[:, None, None] * C[None] - omega[:, None, None] ** 2 * M[None]
            var_e = np.abs(Z) ** 2 @ var_x + var_F
            s = 1.0 / np.sqrt(np.maximum(var_e, np.finfo(float).tiny))
        s = np.where(ok[:, None, :], s, 0.0)
        Aw = (A * s[..., None]).reshape(-1, 3 * P)
        bw = (F * s).ravel()
        Ar = np.vstack([Aw.real, Aw.imag])
        br = np.concatenate([bw.real, bw.imag])
        scale = np.linalg.norm(Ar, axis=0)
        scale[scale == 0] = 1.0
        theta = np.linalg.lstsq(Ar / scale, br, rcond=None)[0] / scale
        out = []
        for part in np.split(theta, 3):
            B = np.zeros((n, n))
            B[i, j] = part
            out.append(B + np.triu(B, 1).T)
        M, C, K = out
    return M, C, K


def eiv_weights(frf: FRFData, weight: np.ndarray, M: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Output-error weights ``1/sigma`` with the reactions' noise seen through the model:
    ``var = var(h) + sum_m |H_model(i, r_m)|^2 var(r_m)``, ``H_model = -w^2 Z^-1``
    (errors in variables, first order); ``weight`` where the file has no reaction variances."""
    var_h, var_r = _variances(frf, weight)
    if var_r is None or not frf.n_react:
        return weight
    outs = list(frf.outputs)
    ridx = [outs.index(lbl) for lbl in frf.reactions]
    w = frf.omega[:, None, None]
    G = np.linalg.inv(K[None] + 1j * w * C[None] - w**2 * M[None])[:, :, ridx] * w**2  # (L, n, n_r)
    var = var_h + np.abs(G) ** 2 @ var_r
    return np.where(np.isfinite(var) & (weight > 0), 1.0 / np.sqrt(var), 0.0)


def fit_mck_with_reactions(frf: FRFData, weight: np.ndarray, start: tuple | None = None,
                           passes: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """M, C, K from the equation-error start, then refined by output error with the weights of
    :func:`eiv_weights` recomputed ``passes`` times at the current model.

    Returns ``(M, C, K, info)``; ``info`` holds the output error of each pass.
    """
    M, C, K = equation_error_mck(frf, weight, start)
    info: dict = {"passes": []}
    for _ in range(passes):
        w = eiv_weights(frf, weight, M, C, K)
        M, C, K, step = refine_mck_output_error(frf, M, C, K, w)
        info["passes"].append(step)
    return M, C, K, info


def refit_where_reactions_undetermined(frf: FRFData, M: np.ndarray, C: np.ndarray, K: np.ndarray,
                                       weight: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict] | None:
    """:func:`fit_mck_with_reactions` for a record whose ``M^-1 D_r`` step 1 cannot determine,
    and whether to take it over the written ``M, C, K``.

    Taken (``info["accepted"]``) when physical (M positive definite, K and C positive
    semi-definite) and its weighted output error (``weight``, the data's noise weights; the
    reactions as known loads) is below the written model's. Not offered on other records: on
    the guide's stand (reactions determined) it took M from 0.12 % to 0.016 % and K from 1.3 %
    to 0.16 % off the simulated truth, but its lowest undamped mode, below the band, from 0.3 %
    to 5.8 % off. Returns None when the fit fails (a singular matrix).
    """
    try:
        Mx, Cx, Kx, info = fit_mck_with_reactions(frf, weight)
        cost, err = model_frf_errors(frf, Mx, Cx, Kx, weight)
    except np.linalg.LinAlgError:
        return None
    cost_start, err_start = model_frf_errors(frf, M, C, K, weight)
    physical = definiteness_problems(Mx, Kx) == 0 and semi_definite(Cx)
    info.update(cost_start=cost_start, frf_relative_rms_error_start=err_start, cost=cost,
                frf_relative_rms_error=err, physical=bool(physical), accepted=bool(physical and cost < cost_start))
    return Mx, Cx, Kx, info
