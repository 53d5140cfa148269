"""Rigid-body modes of a free-free (unsupported) structure in SSID step 2.

A structure tested free has ``r`` rigid-body modes: ``K phi0 = 0`` and, with no damping to
ground, ``C phi0 = 0``. Each is a double root ``lambda = 0`` of Eq. 3.12 with a single
eigenvector ``[phi0; 0]`` and the principal vector ``[0; phi0]`` (the companion matrix
``[[0, I], [-K^, -C^]]`` maps it onto ``[phi0; 0]``): a Jordan block. Step 1 recovers K^, C^
well (noise-free, to 1e-8 or better), but any error ``e`` in the rigid direction splits the
double root into ``+-sqrt(e)`` (real, or an undamped small pair), whose eigenvectors
``[phi0; +-sqrt(e) phi0]`` are nearly parallel. Eq. 3.26 inverts that eigenvector matrix and
Eq. 3.23 fits two nearly cancelling terms ``~ +-1 / (2 sqrt(e) m)`` to a constant mass line, so
M, C, K lose most of the digits step 1 had (4-DOF free chain, noise-free: M 7e-3 off, and 1.2
times off from the exact step-1 matrices, where the roots split on round-off alone).

Here the roots nearest 0 are replaced by rigid-body modes when the data cannot tell them
apart, and the rigid-body modes go into step 2 as Jordan blocks (:func:`ssid.step2.assemble_mck`)
spanned by their invariant subspace, which stays well conditioned.

Which roots. Only roots below the lowest line are candidates: the lines see such a root only
through the mass line and a correction ``(|lambda| / omega)^2`` to it, which noise hides for a
root far enough below. The ``2 r`` roots nearest 0 are replaced by ``r`` rigid-body modes
when the fit of Eq. 3.23 with them is not worse than the fit with the roots as they are by
more than the noise explains: a likelihood-ratio test. With weights ``1/sigma`` the weighted
residual is ``sum |e|^2 / sigma^2``, minus the log-likelihood of complex Gaussian noise, so its
increase under the rigid-body model, when that model is true, is ``chi2_q / 2`` with
``q = r (r + 1)`` (the symmetric stiffness and damping in the rigid-body subspace that the
rigid-body modes set to zero), scaled by the residual's own level (the weights are estimates).
A suspension mode the lines resolve (a grounded structure with a mode below the band,
noise-free) fails the test and is kept as it is.

Near-rigid roots. Roots the test keeps (K not singular there) can be as nearly defective as
rigid-body modes: noise-free data of a free-free structure synthesised in floating point have a
rounding-level stiffness on the rigid-body shapes that the lines, exact to 1e-12, do show
(free-free beam, 2 rigid-body modes: roots near 1e-4 rad/s against a first line of 126 rad/s).
Through their eigenvectors Eq. 3.26 then loses M (7 times off from the maximum-likelihood fit,
1e9 times from total least squares). So the same shapes also enter step 2 as one block with the
stiffness and damping step 1 gives them (:class:`ssid.step2.StateSpaceModes`,
``near_rigid_kc``), and of the two assemblies, through the eigenvectors or through the block,
a physical one (M positive definite, K positive semi-definite) is kept first, then the one whose
written M, C, K reproduce the data better: the eigenvectors where they are well conditioned (a
suspension mode the lines resolve), the block where they are not. Physical first, because the
block's mass is fitted to lines far above the roots it stands for: seen from 20 Hz, a
payload's 1.3-6 Hz suspension modes are a mass line, and a reduced-order fit can give that mass
line a negative mass on one shape to stand for the modes above the band (the free test of
docs/guide.md, section 7: M indefinite, where the eigenvectors write a physical model).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy.stats import chi2

from .errors import IdentificationError
from .modal import companion_matrix
from .step1 import Step1Data, Step1Estimate
from .step1_refine import output_error_cost
from .step2 import ScaleFactors, StateSpaceModes, assemble_mck, fit_scale_factors

__all__ = ["RIGID_BODY_SIGNIFICANCE", "rigid_body_clusters", "with_rigid_body_modes", "near_rigid_modes",
           "semi_definite", "definiteness_problems", "choose_rigid_body_modes"]

#: Significance level of the likelihood-ratio test: roots below the band are kept as they are
#: (K not singular there) only when the data contradict rigid-body modes at this level.
RIGID_BODY_SIGNIFICANCE = 1e-3


def _root_groups(modes: StateSpaceModes) -> list[np.ndarray]:
    """Roots as conjugation-closed groups (a pair, or one real root), nearest 0 first."""
    m, ns = modes.n_pairs, modes.lam.size
    groups = [np.array([i, m + i]) for i in range(m)] + [np.array([j]) for j in range(2 * m, ns)]
    return sorted(groups, key=lambda g: float(np.abs(modes.lam[g[0]])))


def rigid_body_clusters(modes: StateSpaceModes, omega_min: float) -> list[np.ndarray]:
    """Candidate sets of roots for ``r = 1, 2, ...`` rigid-body modes.

    Parameters
    ----------
    modes : StateSpaceModes
        Without rigid-body shapes.
    omega_min : float
        The lowest line, rad/s.

    Returns
    -------
    list of index arrays into ``modes.lam``, the ``r``-th holding the ``2 r`` roots nearest 0:
    all below ``omega_min``, closed under conjugation, and strictly nearer 0 than every other
    root (so that they span an invariant subspace of their own).
    """
    groups = _root_groups(modes)
    mags = [float(np.abs(modes.lam[g[0]])) for g in groups]
    out, taken = [], []
    for k, g in enumerate(groups):
        if mags[k] >= omega_min:
            break
        taken.extend(g.tolist())
        separated = k + 1 == len(groups) or mags[k + 1] > mags[k] * (1 + 1e-9)
        if len(taken) % 2 == 0 and separated:
            out.append(np.array(taken))
    return out


def with_rigid_body_modes(modes: StateSpaceModes, C_hat: np.ndarray, K_hat: np.ndarray,
                          cluster: np.ndarray) -> StateSpaceModes | None:
    """``modes`` with the roots ``cluster`` (``2 r`` of them) replaced by ``r`` rigid-body modes.

    The rigid-body shapes are the displacement partition of the roots' invariant subspace of
    the companion matrix, from an ordered real Schur form: a subspace is well determined where
    the eigenvectors of a nearly defective root are not. Exactly rigid, that partition spans
    the ``r`` shapes (``[[Phi0, 0], [0, Phi0]]``); the ``r`` dominant left singular vectors
    are taken. Returns None when the Schur form does not separate the roots.
    """
    n = modes.n
    r2 = cluster.size
    rest = np.setdiff1d(np.arange(modes.lam.size), cluster)
    lam_abs = np.abs(modes.lam)
    hi = float(lam_abs[cluster].max())
    tau = hi + 0.5 * (float(lam_abs[rest].min()) - hi) if rest.size else np.inf
    comp = companion_matrix(C_hat, K_hat)
    try:
        _, Z, sdim = sla.schur(comp, output="real", sort=lambda re, im: np.hypot(re, im) < tau)
    except np.linalg.LinAlgError:
        # Reordering moved roots across tau: the cluster is not separated from the next root
        # by more than rounding (roots within round-off of a defective double root at 0).
        return None
    if sdim != r2:
        return None
    U = np.linalg.svd(Z[:n, :r2], full_matrices=False)[0]
    phi0 = U[:, : r2 // 2]
    keep_pairs = np.setdiff1d(np.arange(modes.n_pairs), cluster)
    keep_real = np.setdiff1d(np.arange(2 * modes.n_pairs, modes.lam.size), cluster)
    keep = np.concatenate([keep_pairs, keep_pairs + modes.n_pairs, keep_real])
    return StateSpaceModes(lam=modes.lam[keep], theta=modes.theta[:, keep], n_pairs=int(keep_pairs.size),
                           rigid_shapes=phi0)


def near_rigid_modes(rigid: StateSpaceModes, C_hat: np.ndarray, K_hat: np.ndarray) -> StateSpaceModes:
    """``rigid`` (from :func:`with_rigid_body_modes`) with its shapes ``Phi0`` taken as near-rigid:
    their block keeps step 1's stiffness and damping per unit mass ``Phi0^T K^ Phi0``,
    ``Phi0^T C^ Phi0`` instead of zero."""
    phi0 = rigid.rigid_shapes
    return StateSpaceModes(lam=rigid.lam, theta=rigid.theta, n_pairs=rigid.n_pairs, rigid_shapes=phi0,
                           near_rigid_kc=(phi0.T @ K_hat @ phi0, phi0.T @ C_hat @ phi0))


def semi_definite(A: np.ndarray) -> bool:
    """Whether the symmetric ``A`` is positive semi-definite: eigenvalues down to -1e-9 of the
    largest are round-off (on a K's rigid-body modes, a C's undamped motions)."""
    ev = np.linalg.eigvalsh(A)
    return bool(ev.min() >= -1e-9 * np.abs(ev).max())


def definiteness_problems(M: np.ndarray, K: np.ndarray) -> int:
    """How many of (M not positive definite, K not positive semi-definite) hold: 0, 1 or 2."""
    return int(np.linalg.eigvalsh(M).min() <= 0) + int(not semi_definite(K))


def _written_assembly_score(d: Step1Data, modes: StateSpaceModes, fit: ScaleFactors) -> tuple[int, float]:
    """``(problems, output error)`` of the M, C, K that Eq. 3.26 writes from ``modes`` and ``fit``:
    how many of (M not positive definite, K not positive semi-definite) hold, and the weighted
    output error ``sum w^2 |H - H_model|^2`` (``(2, inf)`` when they cannot be written or M is
    singular). Ordered as tuples, a physical assembly ranks first."""
    try:
        M, C, K, _ = assemble_mck(modes, fit.u, fit.rigid_inv_mass)
        M_inv = np.linalg.inv(M)
    except (IdentificationError, np.linalg.LinAlgError):
        return 2, np.inf
    problems = definiteness_problems(M, K)
    # The step-1 form of the written model: M^-1 C, M^-1 K and the forces' M^-1 D_f, M^-1 D_r.
    cost = output_error_cost(d, Step1Estimate(M_inv @ C, M_inv @ K, M_inv[:, d.in_idx], M_inv[:, d.r_idx]))
    return problems, cost


def choose_rigid_body_modes(
    d: Step1Data, C_hat: np.ndarray, K_hat: np.ndarray, modes: StateSpaceModes,
    significance: float = RIGID_BODY_SIGNIFICANCE,
) -> tuple[StateSpaceModes, ScaleFactors, dict]:
    """The modes step 2 assembles, with rigid-body modes where the data allow, and their fit.

    Parameters
    ----------
    d : Step1Data
        The lines (``d.omega`` rad/s) and the weights of Eq. 3.23.
    C_hat, K_hat : (n, n)
        Step 1's ``M^-1 C``, ``M^-1 K`` (``modes`` are their roots).
    modes : StateSpaceModes
        The roots of Eq. 3.12 (:func:`ssid.step2.state_space_modes`).
    significance : float
        Level of the likelihood-ratio test (module docstring).

    Returns
    -------
    (modes, scale factors, info): ``info`` is empty when no root lies below the lowest line;
    otherwise it holds ``n_rigid_body_modes``, the lowest line (rad/s), the magnitudes of the
    roots replaced and, per candidate ``r``, the weighted residuals and the test's limit.
    """
    clusters = rigid_body_clusters(modes, float(np.min(d.omega)))
    if not clusters:
        return modes, fit_scale_factors(d, modes), {}
    n_values = max(int(np.count_nonzero(d.weight > 0)), 1)
    fits = []
    for cluster in clusters:
        cand = with_rigid_body_modes(modes, C_hat, K_hat, cluster)
        if cand is None:
            continue
        try:
            fit = fit_scale_factors(d, cand, with_cost=True)
            soft = fit_scale_factors(d, cand, with_cost=True, rigid_stiffness_test=True)
        except IdentificationError:
            continue
        fits.append((cluster, cand, fit, soft))
    chosen, tests = (modes, None), []
    if fits:
        # The residual per value estimates the noise's level relative to the weights (1 when
        # they are right; above 1 with model error), and the chi2 of the test is scaled by it.
        # As in any comparison of nested fits, it is taken from the most flexible fit: the
        # residual of a fit that holds some low roots badly (each a scale factor on a shape
        # step 1 barely determined) is mostly that misfit, and as a level it would hide the
        # difference under test (a 1.26 Hz suspension mode seen from 20 Hz, whose stiffness
        # the lines do show, was taken as rigid so).
        level = min(soft.cost for *_, soft in fits) / n_values
    for cluster, cand, fit, soft in fits:
        r = cand.n_rigid
        limit = soft.cost + level * chi2.ppf(1.0 - significance, r * (r + 1)) / 2.0
        tests.append({"n_rigid_body_modes": r, "weighted_residual": fit.cost,
                      "weighted_residual_with_stiffness": soft.cost, "limit": float(limit),
                      "roots_abs_rad_per_s": np.sort(np.abs(modes.lam[cluster])).tolist()})
        # Every candidate is tested and the most rigid-body modes that pass are kept: with
        # fewer than the structure has, the others stay as (nearly) defective roots, whose
        # ill-conditioned fit can fail the test for the modes taken.
        if fit.cost <= limit:
            chosen = (cand, fit)
    info = {"n_rigid_body_modes": chosen[0].n_rigid, "lowest_line_rad_per_s": float(np.min(d.omega)),
            "tests": tests}
    if chosen[1] is None:
        chosen = (modes, fit_scale_factors(d, modes))
        if fits:
            # Not rigid: through the eigenvectors, or as one near-rigid block on the shapes of
            # every root below the lowest line (the largest cluster), a physical one first,
            # then whichever writes the M, C, K closer to the data (module docstring).
            near = near_rigid_modes(fits[-1][1], C_hat, K_hat)
            try:
                near_fit = fit_scale_factors(d, near)
            except IdentificationError:
                near_fit = None
            if near_fit is not None:
                scores = {"eigenvectors": _written_assembly_score(d, modes, chosen[1]),
                          "near_rigid_block": _written_assembly_score(d, near, near_fit)}
                used = min(scores, key=scores.get)
                info["near_rigid"] = {"n_shapes": near.n_block, "used": used,
                                      "weighted_output_error": {k: v[1] for k, v in scores.items()},
                                      "problems": {k: v[0] for k, v in scores.items()}}
                if used == "near_rigid_block":
                    chosen = (near, near_fit)
    return chosen[0], chosen[1], info
