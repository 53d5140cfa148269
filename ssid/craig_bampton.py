"""Craig-Bampton models: generalised form, the physical-coordinate TAM, and mode selection.

* :func:`craig_bampton_reduce` -- the classical reduction to fixed-interface modes and
  boundary DOFs (Eqs. 4.13-4.20), ``x = T_CB1 q``.
* :func:`craig_bampton_physical` -- Huang and Craig's transformation ``T_CB2`` back to the
  measured interior DOFs and the boundary DOFs (Eqs. 4.21-4.27): a TAM in physical coordinates.
* :func:`select_fixed_interface_modes` -- which fixed-interface modes to keep so that the TAM
  represents given target modes, by a pivoted factorisation that, unlike the report's
  (section 4.4.2), does not depend on how the modes are scaled (see ``docs/correlation.md``).
* :func:`craig_bampton_form` -- any model (e.g. an SSID result) in Craig-Bampton form:
  fixed-interface eigenvalues, constraint modes and the boundary (constraint-mode) partition of
  the stiffness, the quantities compared in Tables 6.24-6.26.

Index conventions as in :mod:`ssid.tam`: ``boundary`` (b-set) and ``retained`` are full-model
indices; the interior (i-set) is every non-boundary index, ascending. Fixed-interface modes
are columns over the interior, mass-normalised on ``M_ii``, ascending eigenvalue.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .errors import InputError
from .tam import (
    _MODE_RCOND,
    ReducedModel,
    _solve_partition,
    normal_modes,
    omitted_indices,
    reduce_by_transform,
)

__all__ = [
    "CraigBamptonForm",
    "CraigBamptonTAM",
    "ModeSelection",
    "constraint_modes",
    "craig_bampton_form",
    "craig_bampton_physical",
    "craig_bampton_reduce",
    "craig_bampton_tam",
    "craig_bampton_transform",
    "fixed_interface_contributions",
    "fixed_interface_modes",
    "pivoted_selection_report",
    "select_fixed_interface_modes",
]

# Contributions below this fraction of the largest carry no information on the targets
# (they are round-off): the selection then falls back to a scale-free, deterministic rule.
_CONTRIB_FLOOR = 1e-10
# Scores within this relative distance of the best count as a tie, broken by the lower mode
# number; round-off of rescaled modes (1e-15 relative) must never decide a pick.
_TIE_RTOL = 1e-8


def fixed_interface_modes(
    M: np.ndarray, K: np.ndarray, boundary: Sequence[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed-interface normal modes, Eqs. 4.19-4.20: ``K_ii Phi_n = M_ii Phi_n Lambda_n``.

    Returns
    -------
    lam : (n_i,)
        Eigenvalues ``omega^2``, rad^2/s^2, ascending.
    phi_n : (n_i, n_i)
        Mass-normalised on ``M_ii``.
    interior : (n_i,) int
        Full-model indices of the rows of ``phi_n``.
    """
    M = np.asarray(M, dtype=float)
    K = np.asarray(K, dtype=float)
    i = omitted_indices(M.shape[0], boundary)
    try:
        lam, phi = normal_modes(M[np.ix_(i, i)], K[np.ix_(i, i)])
    except np.linalg.LinAlgError:
        raise InputError("M_ii (interior mass) is not positive definite") from None
    return lam, phi, i


def constraint_modes(K: np.ndarray, boundary: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Constraint modes ``Psi_c = -K_ii^-1 K_ib``, Eq. 4.17.

    Returns
    -------
    psi : (n_i, n_b)
        Interior static response to a unit displacement of each boundary DOF, others fixed.
    interior : (n_i,) int
    """
    K = np.asarray(K, dtype=float)
    b = np.asarray(boundary, dtype=int)
    i = omitted_indices(K.shape[0], b)
    return -_solve_partition(K[np.ix_(i, i)], K[np.ix_(i, b)], "K_ii"), i


def craig_bampton_transform(
    M: np.ndarray, K: np.ndarray, boundary: Sequence[int], modes: Sequence[int] | None = None
) -> np.ndarray:
    """``T_CB1 = [[Phi_n, Psi_c], [0, I]]`` (Eq. 4.16) in full-model row order.

    Parameters
    ----------
    modes : sequence of int, optional
        0-based fixed-interface mode numbers to keep (default: all).

    Returns
    -------
    T1 : (n, n_m + n_b)
        Columns: the kept fixed-interface modes, then the boundary DOFs in ``boundary`` order.
    """
    b = np.asarray(boundary, dtype=int)
    lam, phi, i = fixed_interface_modes(M, K, b)
    keep = np.arange(lam.size) if modes is None else np.asarray(modes, dtype=int)
    psi, _ = constraint_modes(K, b)
    n = np.asarray(M).shape[0]
    T1 = np.zeros((n, keep.size + b.size))
    T1[i, : keep.size] = phi[:, keep]
    T1[i, keep.size :] = psi
    T1[b, keep.size :] = np.eye(b.size)
    return T1


def craig_bampton_reduce(
    M: np.ndarray, K: np.ndarray, boundary: Sequence[int], modes: Sequence[int] | None = None
) -> ReducedModel:
    """Craig-Bampton model in generalised coordinates ``q = [q_i; x_b]`` (Eqs. 4.15-4.18).

    ``K_cb = diag(Lambda_n, K_bb_hat)`` and ``M_cb`` has unit modal mass, the coupling
    ``M_nb`` and the boundary mass. With every fixed-interface mode kept it is the full model
    in other coordinates: the same natural frequencies.
    """
    T1 = craig_bampton_transform(M, K, boundary, modes)
    return ReducedModel(reduce_by_transform(M, T1), reduce_by_transform(K, T1), T1)


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


# ----------------------------------------------------------------------------------------------
# The Craig-Bampton TAM in physical coordinates (Huang and Craig)
# ----------------------------------------------------------------------------------------------


def craig_bampton_physical(
    M: np.ndarray,
    K: np.ndarray,
    retained: Sequence[int],
    boundary: Sequence[int],
    modes: Sequence[int],
) -> ReducedModel:
    """Craig-Bampton TAM over the measured DOFs, Eqs. 4.21-4.27.

    With the measured interior DOFs ``r`` (``retained`` minus ``boundary``),
    ``x_r = Phi_nr q_i + Psi_cr x_b`` (Eq. 4.23) is solved for ``q_i``:

        ``T_CB2 = [[Phi_nr^-1, -Phi_nr^-1 Psi_cr], [0, I]]``   (Eq. 4.24, corrected)

    and ``M_CB = T_CB2^T T_CB1^T M T_CB1 T_CB2`` (Eqs. 4.25-4.26). The report's
    ``-(Phi_nr^T Phi_nr)^-1 Psi_cr^T`` cannot be right (its shape is n_m x n_r, not n_m x n_b);
    the derivation gives ``-(Phi_nr^T Phi_nr)^-1 Phi_nr^T Psi_cr``, which for the square
    ``Phi_nr`` used here is ``-Phi_nr^-1 Psi_cr``.

    ``T_CB2`` is invertible, so the TAM spans the same space as ``[Phi_n, Psi_c]``: its natural
    frequencies are those of :func:`craig_bampton_reduce` with the same modes.

    Parameters
    ----------
    M, K : (n, n)
    retained : sequence of int, (n_a,)
        TAM DOFs (measured interior and all boundary DOFs), in the TAM's order.
    boundary : sequence of int, (n_b,)
        Interface DOFs; each must be in ``retained``.
    modes : sequence of int, (n_a - n_b,)
        0-based fixed-interface mode numbers, one per measured interior DOF.

    Returns
    -------
    ReducedModel
        ``T`` (n, n_a) with columns in ``retained`` order.
    """
    a = np.asarray(retained, dtype=int)
    b = np.asarray(boundary, dtype=int)
    if not np.isin(b, a).all():
        raise InputError("every interface (boundary) DOF must be a retained DOF of the C-B TAM")
    r = a[~np.isin(a, b)]
    modes = np.asarray(modes, dtype=int)
    if modes.size != r.size:
        raise InputError(
            f"the C-B TAM needs one fixed-interface mode per measured interior DOF "
            f"({r.size}), got {modes.size}"
        )
    T1 = craig_bampton_transform(M, K, b, modes)  # columns [q (n_r), x_b (n_b)]
    i = omitted_indices(np.asarray(M).shape[0], b)
    pos = np.searchsorted(i, r)
    phi_nr = T1[i][pos, : r.size]
    psi_r = T1[i][pos, r.size :]
    if r.size and np.linalg.cond(phi_nr) * _MODE_RCOND > 1:
        raise InputError("the selected fixed-interface modes are not independent at the measured DOFs")
    inv = sla.solve(phi_nr, np.eye(r.size)) if r.size else np.zeros((0, 0))
    T2 = np.zeros((r.size + b.size, r.size + b.size))  # from [x_r; x_b] to [q; x_b]
    T2[: r.size, : r.size] = inv
    T2[: r.size, r.size :] = -inv @ psi_r
    T2[r.size :, r.size :] = np.eye(b.size)
    T = T1 @ T2
    # Columns are [r..., b...]; put them in the caller's retained order.
    col_of = {int(d): k for k, d in enumerate(np.concatenate([r, b]))}
    T = T[:, [col_of[int(d)] for d in a]]
    return ReducedModel(reduce_by_transform(M, T), reduce_by_transform(K, T), T)


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
    boundary: Sequence[int],
    targets: Sequence[int] | None = None,
) -> CraigBamptonTAM:
    """C-B TAM with its fixed-interface modes selected for the target modes.

    Parameters
    ----------
    targets : sequence of int, optional
        0-based full-model target mode numbers; default the lowest ``n_a``.
    """
    a = np.asarray(retained, dtype=int)
    b = np.asarray(boundary, dtype=int)
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


# ----------------------------------------------------------------------------------------------
# Any model in Craig-Bampton form (Tables 6.24-6.26)
# ----------------------------------------------------------------------------------------------


@dataclass
class CraigBamptonForm:
    """A model's Craig-Bampton quantities with every fixed-interface mode.

    Attributes
    ----------
    interior, boundary : int arrays
        Model indices of the interior and boundary DOFs.
    eigenvalues : (n_i,)
        Fixed-interface eigenvalues ``Lambda_r``, rad^2/s^2, ascending (Tables 6.24-6.26).
    modes : (n_i, n_i)
        Fixed-interface modes, mass-normalised on ``M_ii``.
    constraint_modes : (n_i, n_b)
        ``Psi_c = -K_ii^-1 K_ib``.
    boundary_stiffness : (n_b, n_b)
        Constraint-mode partition of the C-B stiffness, ``K_bb + K_bi Psi_c`` (N/m): the
        static stiffness at the interface with the interior free.
    boundary_mass : (n_b, n_b)
        ``[Psi_c; I]^T M [Psi_c; I]``: the rigid/static mass seen at the interface.
    coupling_mass : (n_i, n_b)
        ``Phi_n^T (M_ii Psi_c + M_ib)``: modal participation of the interface motion.
    """

    interior: np.ndarray
    boundary: np.ndarray
    eigenvalues: np.ndarray
    modes: np.ndarray
    constraint_modes: np.ndarray
    boundary_stiffness: np.ndarray
    boundary_mass: np.ndarray
    coupling_mass: np.ndarray

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Fixed-interface natural frequencies, Hz, (n_i,)."""
        return np.sqrt(np.abs(self.eigenvalues)) * np.sign(self.eigenvalues) / (2 * np.pi)


def craig_bampton_form(M: np.ndarray, K: np.ndarray, boundary: Sequence[int]) -> CraigBamptonForm:
    """Put a model (analytical, a TAM or an SSID result) into Craig-Bampton form.

    An SSID model over measured DOFs that include the interface DOFs holds everything a C-B
    model needs (section 6.5): its interior partition gives the fixed-interface modes and its
    condensed boundary stiffness gives the constraint-mode data.
    """
    M = np.asarray(M, dtype=float)
    K = np.asarray(K, dtype=float)
    b = np.asarray(boundary, dtype=int)
    lam, phi, i = fixed_interface_modes(M, K, b)
    psi, _ = constraint_modes(K, b)
    Kbb = K[np.ix_(b, b)] + K[np.ix_(b, i)] @ psi
    S = np.zeros((M.shape[0], b.size))
    S[i] = psi
    S[b] = np.eye(b.size)
    Mbb = reduce_by_transform(M, S)
    Mnb = phi.T @ (M[np.ix_(i, i)] @ psi + M[np.ix_(i, b)])
    return CraigBamptonForm(i, b, lam, phi, psi, (Kbb + Kbb.T) / 2, Mbb, Mnb)
