"""How well step 1 determines ``M^-1 D_r`` (the reactions' columns) on a record: a Cramer-Rao bound.

Step 1 fits ``h + C^ h/(jw) - K^ h/w^2 - D^_f e_j - D^_r r = 0`` with ``D^_r = M^-1 D_r`` free.
When a reaction is, over the band, nearly a spring and a dashpot on its own DOF's motion,
``r ~ -(k + j w c) x_i = (k h_i/w^2 - c h_i/(j w))``, its regressor ``-r`` is nearly a
combination of the ``h_i/(jw)`` and ``-h_i/w^2`` columns of ``C^`` and ``K^`` at that DOF:
``D^_r[:, m] + v``, ``C^[:, i] - c v``, ``K^[:, i] - k v`` fit the data alike for any ``v``.
Only the small rest of ``r`` (what the stand's own mass makes of it) tells them apart. The
data do not lack the information (``D_r`` is known: in physical coordinates
``M a + C v + K x = D_f f + D_r r`` has no such freedom); step 1's division by M drops it.
Step 2 then takes ``D_r`` as known and the error lands in M, C, K.

Measured (QA's soft stand, ``stand_k`` 2e4 N/m, ``stand_c`` 400 N s/m, 20 kg post mass, the
payload's 16 Z DOFs, 94 lines 20-1500 Hz, ~3e-5 noise): each reaction is 98.4-99.0 % (in
norm) ``-(k + j w c) x_i`` with k ~ 1.1e4 N/m, c ~ 405 N s/m; at the file's (calibrated)
variances the bound below is 48-211 % of each ``D^_r`` column and 400-2200 % of the
interface columns of ``C^``, correlated -0.990 to -0.9997 with them. The guide's stand (2e6
N/m): 89 % of each reaction is not such a spring-dashpot, the bound 0.26-0.65 %.
"""

from __future__ import annotations

import numpy as np

from .frf import FRFData
from .noise import weight_of_variance
from .step1 import Step1Data, Step1Estimate, _equation_weights, _line_blocks, step1_data, step1_regressors
from .step1_refine import _NormalEquations, errors_in_variables_cost

__all__ = ["REACTION_SPREAD_MAX", "ML_SPREAD_MAX_UNKNOWNS", "reaction_spread", "stand_impedance_fit",
           "undetermined_reactions_warning"]

#: A reaction's ``M^-1 D_r`` column is taken as undetermined by the data when its Cramer-Rao
#: standard deviation, at the fitted estimate, exceeds this fraction of its norm. Measured: the
#: guide's stand 0.0026-0.0065 (payload) and 0.0004-0.0006 (tests' chain); soft stands
#: 0.14-0.54 (payload, 0.48-2.1 at the true model) and 0.14 (chain), M then 29-240 % off;
#: the stiff stand (interface motion in the noise) 0.11-0.21.
REACTION_SPREAD_MAX = 0.05
#: Step-1 unknowns (n p) above which the bound is not computed: its normal matrix is (n p)^2.
ML_SPREAD_MAX_UNKNOWNS = 3000


def stand_impedance_fit(frf: FRFData) -> list[dict]:
    """Each reaction fitted as ``-(k + j w c) x_i`` on its own DOF's motion ``x_i = -h_i / w^2``.

    Returns one dict per reaction: ``reaction``, ``k_n_per_m``, ``c_n_s_per_m`` (real, least
    squares over the valid lines and inputs) and ``share``, the fraction of the reaction's
    norm the fit holds (1: the reaction is exactly a spring-dashpot on the interface motion).
    """
    out = []
    valid = frf.valid_mask()
    w = frf.omega[:, None]
    for m, i in enumerate(frf.reaction_index()):
        ok = valid[:, i, :]
        x = np.where(ok, -np.nan_to_num(frf.H[:, i, :]) / w**2, 0.0)
        r = np.where(ok, frf.H_reaction[:, m, :], 0.0)
        G = np.stack([x.ravel(), (1j * w * x).ravel()], axis=1)
        A = np.vstack([G.real, G.imag])
        y = -np.concatenate([r.ravel().real, r.ravel().imag])
        (k, c), *_ = np.linalg.lstsq(A, y, rcond=None)
        rest = np.linalg.norm(r.ravel() + G @ np.array([k, c]))
        norm = np.linalg.norm(r)
        out.append({"reaction": frf.reactions[m], "k_n_per_m": float(k), "c_n_s_per_m": float(c),
                    "share": float(1.0 - rest / norm) if norm > 0 else 0.0})
    return out


def reaction_spread(frf: FRFData, d: Step1Data, est: Step1Estimate) -> np.ndarray | None:
    """Cramer-Rao standard deviation of each ``D^_r`` column over its norm, (n_r,), at ``est``.

    The Fisher matrix of step 1's errors-in-variables cost (``J^T S^-1 J``, the normal matrix
    of the SK iterations) at the estimate. Noise: the file's variances when it has both
    ``H_var`` and ``H_reaction_var`` (stated, absolute); otherwise step 1's weights (1/sigma up
    to a common factor), scaled so that the cost at ``est`` equals the number of equations.
    None when the bound is not computed (no reactions, too many unknowns, singular matrix).
    """
    if d.n_r == 0 or d.n * d.p > ML_SPREAD_MAX_UNKNOWNS:
        return None
    if frf.H_var is not None and frf.H_reaction_var is not None:
        var = np.where(frf.valid_mask(), np.nan_to_num(frf.H_var, nan=0.0), 0.0)
        with np.errstate(divide="ignore"):
            w = weight_of_variance(var)
            w_r = 1.0 / np.sqrt(np.asarray(frf.H_reaction_var, float))
        dd = step1_data(frf, w, w_r)
        scale = 1.0
    else:
        dd = d
        n_eq = int(np.count_nonzero(d.col_ok)) * d.n
        cost = errors_in_variables_cost(d, est)
        if not (np.isfinite(cost) and cost > 0 and n_eq):
            return None
        scale = cost / n_eq  # variance factor of the weights
    ne = _NormalEquations(dd.n, dd.p)
    for sl in _line_blocks(dd):
        W = _equation_weights(dd, est, sl)
        ne.add(step1_regressors(dd, dd.H[sl], sl), W, np.zeros(W.shape[:3], dtype=complex))
    N, _ = ne.matrix()
    s = np.sqrt(np.abs(np.diag(N)))
    s[s == 0] = 1.0
    try:
        cov = np.linalg.inv(N / s[:, None] / s[None, :]) / s[:, None] / s[None, :]
    except np.linalg.LinAlgError:
        return None
    sd = np.sqrt(np.abs(np.diag(cov)) * scale).reshape(dd.n, dd.p)
    c0 = 2 * dd.n + dd.n_in
    norms = np.linalg.norm(est.Dr_hat, axis=0)
    return np.linalg.norm(sd[:, c0:], axis=0) / np.where(norms > 0, norms, np.inf)


def undetermined_reactions_warning(frf: FRFData, d: Step1Data, est: Step1Estimate) -> tuple[str | None, dict]:
    """The warning (or None) and ``info`` when step 1 cannot determine a reaction's ``M^-1 D_r``.

    ``info``: ``spread`` (per reaction, :func:`reaction_spread`) and ``stand_fit``
    (:func:`stand_impedance_fit`).
    """
    spread = reaction_spread(frf, d, est)
    if spread is None:
        return None, {}
    fits = stand_impedance_fit(frf)
    info = {"spread": {f["reaction"]: float(s) for f, s in zip(fits, spread)}, "stand_fit": fits}
    bad = [(f, s) for f, s in zip(fits, spread) if not s <= REACTION_SPREAD_MAX]
    if not bad:
        return None, info
    names = ", ".join(f["reaction"] for f, _ in bad)
    worst = max(s for _, s in bad)
    like = [f for f, _ in bad if f["share"] >= 0.9]
    if like:
        cause = ("over the band the reaction(s) are {} a spring and dashpot on their own DOF's motion "
                 "({}), so step 1 (which divides by M and fits M^-1 D_r freely) cannot tell the measured "
                 "reaction from the substructure's own stiffness and damping there: the stand is too "
                 "soft and/or too damped for its post masses to show in the band").format(
                     "/".join(f"{100 * f['share']:.1f} %" for f in like),
                     "; ".join(f"{f['reaction']}: k {f['k_n_per_m']:.3g} N/m, c {f['c_n_s_per_m']:.3g} N s/m"
                               for f in like))
    else:
        cause = ("the interface motion and reactions carry too little signal above their noise to "
                 "separate the reactions from the substructure's own stiffness and damping at those "
                 "DOFs (a stand much stiffer than the substructure holds the interface nearly still); use a stand "
                 "nearer the substructure's interface stiffness, or measure the interface with less noise")
    return (f"step 1 cannot determine the reaction term M^-1 D_r at {names} from these data (its "
            f"Cramer-Rao spread is up to {100 * worst:.0f} % of its size, limit "
            f"{100 * REACTION_SPREAD_MAX:.0f} %): {cause}. The error lands in M, C, K and in the "
            "damping at those DOFs; measuring higher in frequency does not help"), info


def reaction_fit_note(fit: dict) -> str:
    """What :func:`ssid.reaction_fit.refit_where_reactions_undetermined` made of it (``fit``, its
    info), to follow the warning of :func:`undetermined_reactions_warning`."""
    said = (f". Step 2's model reproduces the FRFs to {100 * fit['frf_relative_rms_error_start']:.3g} %; refitted "
            "in physical coordinates (where D_r is known), with the measured reactions as known loads and "
            "their noise weighted (output error), M, C, K reproduce them to "
            f"{100 * fit['frf_relative_rms_error']:.3g} %")
    if fit["accepted"]:
        return f"{said} and are the model written (info['reaction_fit'])"
    return f"{said} but are not written (not physical, or not closer to the data)"
