"""The Craig-Bampton TAM in physical coordinates and the choice of its fixed-interface modes.

* :func:`select_fixed_interface_modes` -- which fixed-interface modes to keep so that the TAM
  represents given target modes, by a pivoted factorisation that, unlike the report's
  (section 4.4.2), does not depend on how the modes are scaled (see ``docs/correlation.md``);
  :func:`fixed_interface_contributions` and :func:`pivoted_selection_report` are the report's
  measures behind it.
* :func:`craig_bampton_tam` -- that selection and :func:`ssid.craig_bampton.craig_bampton_physical`
  together: the TAM for given retained DOFs, interface and target modes.

Index conventions as in :mod:`ssid.craig_bampton`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .craig_bampton import constraint_modes, craig_bampton_physical, fixed_interface_modes
from .errors import InputError
from .model_checks import index_array, model_matrices
from .tam import ReducedModel, normal_modes, omitted_indices

__all__ = [
    "CraigBamptonTAM",
    "ModeSelection",
    "craig_bampton_tam",
    "fixed_interface_contributions",
    "pivoted_selection_report",
    "select_fixed_interface_modes",
]

# Contributions below this fraction of the largest carry no information on the targets
# (they are round-off): the selection then falls back to a scale-free, deterministic rule.
_CONTRIB_FLOOR = 1e-10
# Scores within this relative distance of the best count as a tie, broken by the lower mode
# number; round-off of rescaled modes (1e-15 relative) must never decide a pick.
_TIE_RTOL = 1e-8


# ----------------------------------------------------------------------------------------------
# Selection of the fixed-interface modes (section 4.4.2)
# ----------------------------------------------------------------------------------------------


def fixed_interface_contributions(
    M: np.ndarray,
    K: np.ndarray,
    boundary: Sequence[int],
    phi_t: np.ndarray,
    fi_modes: np.ndarray | None = None,
) -> np.ndarray:
    """Scale-free share of each target mode carried by each fixed-interface mode.

    In a Craig-Bampton basis a target mode ``phi_t`` is its boundary motion spread by the
    constraint modes plus the relative interior motion ``y_t = phi_t,i - Psi_c phi_t,b``, and
    only ``y_t`` needs fixed-interface modes. The share of fixed-interface mode ``k`` is the
    mass-weighted MAC

        ``c_kt = (phi_k^T M_ii y_t)^2 / ((phi_k^T M_ii phi_k) (y_t^T M_ii y_t))``,

    the fraction of the kinetic-energy norm of ``y_t`` along ``phi_k``. It is unchanged by any
    rescaling (or sign change) of ``phi_k`` or ``phi_t``, and over all fixed-interface modes the
    shares of one target add to 1 (they are ``M_ii``-orthogonal).

    Parameters
    ----------
    M, K : (n, n)
    boundary : sequence of int, (n_b,)
    phi_t : (n, n_t)
        Target modes of the full model, any scaling.
    fi_modes : (n_i, n_fi), optional
        Fixed-interface modes, any scaling (default: :func:`fixed_interface_modes`).

    Returns
    -------
    c : (n_fi, n_t)
        In [0, 1]; a target that is pure constraint-mode motion (``y_t = 0``, e.g. a rigid-body
        mode) needs no fixed-interface mode and has a zero column.
    """
    M = np.asarray(M, dtype=float)
    b = np.asarray(boundary, dtype=int)
    psi, i = constraint_modes(K, b)
    if fi_modes is None:
        fi_modes = fixed_interface_modes(M, K, b)[1]
    phi_t = np.asarray(phi_t, dtype=float)
    Mii = M[np.ix_(i, i)]
    y = phi_t[i] - psi @ phi_t[b]
    proj = fi_modes.T @ Mii @ y  # (n_fi, n_t)
    m_fi = np.einsum("ik,ij,jk->k", fi_modes, Mii, fi_modes)
    m_y = np.einsum("ik,ij,jk->k", y, Mii, y)
    m_t = np.einsum("ik,ij,jk->k", phi_t, M, phi_t)
    # Relative to the whole target's norm, so that the test does not depend on its scale.
    moving = m_y > 1e-12 * m_t
    c = np.zeros(proj.shape)
    c[:, moving] = proj[:, moving] ** 2 / (m_fi[:, None] * m_y[None, moving])
    return np.clip(c, 0.0, 1.0)


@dataclass
class ModeSelection:
    """Result of :func:`select_fixed_interface_modes`.

    Attributes
    ----------
    modes : (n_r,) int
        Selected fixed-interface mode numbers (0-based, ascending).
    order : (n_r,) int
        The same, in the order the pivoting picked them.
    contributions : (n_fi, n_t)
        :func:`fixed_interface_contributions`.
    weight : (n_fi,)
        ``sqrt(sum_t c_kt)``: each mode's total contribution, the pivoting's column weight.
    captured : (n_t,)
        Share of each target's relative interior motion in the selected modes' span
        (1: the target is represented exactly by the TAM).
    """

    modes: np.ndarray
    order: np.ndarray
    contributions: np.ndarray
    weight: np.ndarray
    captured: np.ndarray


def select_fixed_interface_modes(
    M: np.ndarray,
    K: np.ndarray,
    measured: Sequence[int],
    boundary: Sequence[int],
    phi_t: np.ndarray,
    fi_modes: np.ndarray | None = None,
) -> ModeSelection:
    """Fixed-interface modes contributing most to the targets, one per measured interior DOF.

    A pivoted (Gram-Schmidt / column-pivoted QR) factorisation of the measured partition
    ``Phi_nr`` (n_r, n_fi) with every column first made scale-free and weighted:

    1. each column is divided by its Euclidean norm over the measured rows (so the mode's
       scaling no longer matters), and multiplied by ``w_k = sqrt(sum_t c_kt)``, the mode's
       scale-free contribution to the targets (:func:`fixed_interface_contributions`);
    2. the pivot is the column with the largest remaining norm after the picked columns are
       projected out: contribution times independence at the measured DOFs, so that the
       selected ``Phi_nr`` is invertible (a mode on a node line of the measured DOFs is not
       picked, which is why the report needed full pivoting);
    3. when no remaining mode contributes (all ``c_kt`` at round-off), the lowest-numbered
       mode that is still well independent is taken.

    The report pivoted on ``Phi_nr`` as scaled (:func:`pivoted_selection_report`), so
    a rescaled mode could win a pivot; here no step sees the scaling.

    Parameters
    ----------
    M, K : (n, n)
    measured : sequence of int, (n_r,)
        Measured interior DOFs (no boundary DOF).
    boundary : sequence of int, (n_b,)
    phi_t : (n, n_t)
        Target modes of the full model, any scaling.
    fi_modes : (n_i, n_fi), optional
        Fixed-interface modes, any scaling and ascending frequency (default: computed).

    Returns
    -------
    ModeSelection
    """
    b = np.asarray(boundary, dtype=int)
    r = np.asarray(measured, dtype=int)
    if np.intersect1d(r, b).size:
        raise InputError("a measured interior DOF is also a boundary DOF")
    if fi_modes is None:
        fi_modes = fixed_interface_modes(M, K, b)[1]
    i = omitted_indices(np.asarray(M).shape[0], b)
    pos = np.searchsorted(i, r)
    c = fixed_interface_contributions(M, K, b, phi_t, fi_modes)
    w = np.sqrt(c.sum(axis=1))
    w = np.where(w > np.sqrt(_CONTRIB_FLOOR) * max(w.max(), 1e-300), w, 0.0)

    phi_nr = np.asarray(fi_modes, dtype=float)[pos]
    col = np.linalg.norm(phi_nr, axis=0)
    full = np.linalg.norm(fi_modes, axis=0)
    seen = col > 1e-10 * full  # a mode that is zero at every measured DOF cannot be used
    U = np.where(seen, phi_nr / np.where(seen, col, 1.0), 0.0)

    n_r = r.size
    if n_r > fi_modes.shape[1]:
        raise InputError(f"{n_r} measured interior DOFs but only {fi_modes.shape[1]} fixed-interface modes")
    Q = np.zeros((n_r, 0))
    order: list[int] = []
    for _ in range(n_r):
        R = U - Q @ (Q.T @ U)
        res = np.linalg.norm(R, axis=0)
        res[order] = 0.0
        score = w * res
        if score.max() > 1e-6 * max(w.max(), 1e-300):
            k = int(np.flatnonzero(score >= score.max() * (1 - _TIE_RTOL))[0])
        elif res.max() > 1e-8:
            k = int(np.flatnonzero(res >= 0.5 * res.max())[0])
        else:
            raise InputError(
                "the measured interior DOFs do not see enough independent fixed-interface "
                "modes for a Craig-Bampton TAM (choose other measured DOFs)"
            )
        order.append(k)
        Q = np.column_stack([Q, R[:, k] / res[k]])
    modes = np.sort(np.asarray(order, dtype=int))
    captured = c[modes].sum(axis=0)
    return ModeSelection(modes, np.asarray(order, dtype=int), c, w, captured)


def pivoted_selection_report(phi_nr: np.ndarray, n_select: int) -> np.ndarray:
    """The report's selection: Gaussian elimination with full pivoting on ``Phi_nr``.

    Kept to show the scale dependence that section 4.4.2 found: the first pivot is the
    largest entry of ``Phi_nr``, so multiplying one mode by a large factor makes it be picked.
    Use :func:`select_fixed_interface_modes`.

    Returns
    -------
    (n_select,) int
        Column (mode) numbers in pivot order.
    """
    A = np.array(phi_nr, dtype=float)
    rows = list(range(A.shape[0]))
    cols = list(range(A.shape[1]))
    picked = []
    for _ in range(n_select):
        sub = np.abs(A[np.ix_(rows, cols)])
        ri, ci = np.unravel_index(np.argmax(sub), sub.shape)
        p, q = rows[ri], cols[ci]
        picked.append(q)
        if A[p, q] != 0:
            A -= np.outer(A[:, q] / A[p, q], A[p])
        rows.remove(p)
        cols.remove(q)
    return np.asarray(picked, dtype=int)


@dataclass
class CraigBamptonTAM:
    """A C-B TAM and how its fixed-interface modes were chosen."""

    reduced: ReducedModel
    selection: ModeSelection
    fixed_interface_eigenvalues: np.ndarray  # (n_fi,) all of them, rad^2/s^2


def craig_bampton_tam(
    M: np.ndarray,
    K: np.ndarray,
    retained: Sequence[int],
    boundary: Sequence[int] | None,
    targets: Sequence[int] | None = None,
) -> CraigBamptonTAM:
    """C-B TAM with its fixed-interface modes selected for the target modes.

    Parameters
    ----------
    targets : sequence of int, optional
        0-based full-model target mode numbers; default the lowest ``n_a``.

    Raises
    ------
    InputError
        No boundary DOF, every DOF a boundary DOF, a boundary DOF not retained, indices or
        matrices that are not a model's (:mod:`ssid.model_checks`), M not positive definite.
    """
    if boundary is None or len(boundary) == 0:
        raise InputError("the Craig-Bampton TAM needs the interface (boundary) DOFs")
    M, K = model_matrices(M, K)
    a = index_array(retained, M.shape[0])
    b = index_array(boundary, M.shape[0], "boundary")
    if not np.isin(b, a).all():
        raise InputError("every interface (boundary) DOF must be a retained DOF of the C-B TAM")
    try:
        _, phi = normal_modes(M, K)
    except np.linalg.LinAlgError:
        raise InputError("M is not positive definite") from None
    t = np.arange(min(a.size, phi.shape[1])) if targets is None else np.asarray(targets, int)
    if t.size == 0 or t.min() < 0 or t.max() >= phi.shape[1]:
        raise InputError(f"target modes must be mode numbers between 1 and {phi.shape[1]}")
    lam_fi, phi_fi, _ = fixed_interface_modes(M, K, b)
    sel = select_fixed_interface_modes(M, K, a[~np.isin(a, b)], b, phi[:, t], phi_fi)
    red = craig_bampton_physical(M, K, a, b, sel.modes)
    return CraigBamptonTAM(red, sel, lam_fi)
