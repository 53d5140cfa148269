"""Craig-Bampton models: generalised form and the physical-coordinate transformation.

* :func:`craig_bampton_reduce` -- the classical reduction to fixed-interface modes and
  boundary DOFs (Eqs. 4.13-4.20), ``x = T_CB1 q``.
* :func:`craig_bampton_physical` -- Huang and Craig's transformation ``T_CB2`` back to the
  measured interior DOFs and the boundary DOFs (Eqs. 4.21-4.27): a TAM in physical coordinates.
* :mod:`ssid.craig_bampton_tam` -- which fixed-interface modes to keep for given target
  modes (section 4.4.2), and the C-B TAM built with them.
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
from .model_checks import index_array, model_matrices
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
    "constraint_modes",
    "craig_bampton_form",
    "craig_bampton_physical",
    "craig_bampton_reduce",
    "craig_bampton_transform",
    "fixed_interface_modes",
]

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

    Raises
    ------
    InputError
        M, K or the boundary indices not those of a model (:mod:`ssid.model_checks`), every
        DOF a boundary DOF, or ``M_ii`` not positive definite.
    """
    M, K = model_matrices(M, K)
    i = omitted_indices(M.shape[0], boundary, "boundary")
    if i.size == 0:
        # No interior: no fixed-interface mode, and numpy's "argmax of an empty sequence".
        raise InputError(f"every one of the {M.shape[0]} DOFs is a boundary (interface) DOF: no interior "
                         "DOF is left for fixed-interface modes")
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
    b = index_array(boundary, K.shape[0], "boundary")
    i = omitted_indices(K.shape[0], b, "boundary")
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
    lam, phi, i = fixed_interface_modes(M, K, boundary)
    b = np.asarray(boundary, dtype=int)  # checked by fixed_interface_modes
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
    n = np.shape(M)[0]
    a = index_array(retained, n)
    b = index_array(boundary, n, "boundary")
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
    M, K = model_matrices(M, K)
    lam, phi, i = fixed_interface_modes(M, K, boundary)
    b = np.asarray(boundary, dtype=int)  # checked by fixed_interface_modes
    psi, _ = constraint_modes(K, b)
    Kbb = K[np.ix_(b, b)] + K[np.ix_(b, i)] @ psi
    S = np.zeros((M.shape[0], b.size))
    S[i] = psi
    S[b] = np.eye(b.size)
    Mbb = reduce_by_transform(M, S)
    Mnb = phi.T @ (M[np.ix_(i, i)] @ psi + M[np.ix_(i, b)])
    return CraigBamptonForm(i, b, lam, phi, psi, (Kbb + Kbb.T) / 2, Mbb, Mnb)
