"""Test-analysis models (TAMs): full M, K reduced to the measured (retained) DOFs.

Every TAM here is a Ritz transformation ``x = T x_a`` of the full model (Eq. 4.1),
``M_a = T^T M T``, ``K_a = T^T K T``, with ``T`` of shape ``(n, n_a)`` whose rows at the
retained DOFs are the identity. They differ in how the omitted DOFs follow the retained ones:

=================  ==============================================  ==================
function           interpolation of the omitted (o-set) DOFs        report
=================  ==============================================  ==================
guyan_reduce       static (constraint modes)                        Eqs. 4.2-4.4
irs_reduce         static + first-order inertia correction          Eqs. 4.5-4.6
serep_reduce       target modes (modal / SEREP TAM)                 Eqs. 4.7-4.8
hybrid_tam         static, corrected to keep the target modes       Eqs. 4.9-4.10
=================  ==============================================  ==================

The Craig-Bampton TAM in physical coordinates is in :mod:`ssid.craig_bampton`.

Index conventions: ``retained`` is a sequence of row/column indices of the full model (the
a-set, in the order wanted for the TAM); the o-set is every other index, ascending. Modes are
columns, mass-normalised (``Phi^T M Phi = I``) and in ascending frequency unless stated.
Eigenvalues are ``omega^2`` in rad^2/s^2; frequencies are in Hz where the name says ``_hz``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from .errors import InputError
from .model_checks import (
    RIGID_ROUNDOFF_RTOL,
    MassNotPositiveDefinite,
    dof_indices,
    index_array,
    model_matrices,
    n_unstable_modes,
    omitted_indices,
    require_elastic_modes,
    require_stable_stiffness,
)
from .semidefinite_modes import largest_entry_positive, normal_modes_semidefinite

__all__ = ["RIGID_ROUNDOFF_RTOL", "TAM_METHODS", "MassNotPositiveDefinite", "ReducedModel", "dof_indices",
           "guyan_reduce", "guyan_transform", "hybrid_tam", "hybrid_transform", "irs_reduce",
           "irs_transform", "n_unstable_modes", "natural_frequencies_hz", "normal_modes",
           "omitted_indices", "reduce_by_transform", "reduce_to_tam", "require_elastic_modes",
           "require_stable_stiffness", "retained_share", "serep_reduce", "serep_transform"]

#: Names accepted by :func:`reduce_to_tam` (and ``ssidlab correlate --tam``).
TAM_METHODS = ("guyan", "irs", "serep", "hybrid", "cb")

# A partition whose 2-norm condition number exceeds this is treated as singular: a solve with
# it would lose every significant digit of double precision.
_COND_MAX = 1e13
# Mode shapes from an eigensolver are only as good as ~1e-8 relative where frequencies are
# close, so a mode partition with a smaller relative singular value is treated as rank
# deficient: inverting it would amplify that error beyond any use.
_MODE_RCOND = 1e-8


class ReducedModel(NamedTuple):
    """A reduced model and the transformation that made it.

    Attributes
    ----------
    M, K : (n_a, n_a)
        Reduced mass (kg) and stiffness (N/m), ``T^T M T`` and ``T^T K T``.
    T : (n, n_a)
        Transformation from the retained DOFs to all DOFs, ``x = T x_a``.
    """

    M: np.ndarray
    K: np.ndarray
    T: np.ndarray


# ----------------------------------------------------------------------------------------------
# Eigen helpers (the index and model checks are in ssid.model_checks)
# ----------------------------------------------------------------------------------------------


def normal_modes(M: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``omega^2`` (rad^2/s^2, ascending) and mass-normalised modes of (K, M).

    Returns
    -------
    lam : (n,)
    phi : (n, n), ``phi^T M phi = I``; each column's largest-magnitude entry is positive,
        so that the sign of a mode does not flip between runs.

    Raises
    ------
    MassNotPositiveDefinite
        ``M`` is not positive definite: an InputError, and a ``numpy.linalg.LinAlgError`` for
        the callers that name the model in their own message.
    InputError
        M or K not finite, not square or not of one size.
    """
    try:
        lam, phi = sla.eigh(np.asarray(K, dtype=float), np.asarray(M, dtype=float))
    except np.linalg.LinAlgError:
        raise MassNotPositiveDefinite("M is not positive definite: (K, M) has no normal modes (a negative "
                                      "or zero mass, or massless DOFs to reduce out first)") from None
    except ValueError as exc:  # scipy's: NaN or Inf, not square, sizes that differ
        raise InputError(f"no normal modes of these M, K: {exc}") from None
    return largest_entry_positive(lam, phi)


def natural_frequencies_hz(M: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Undamped natural frequencies of (K, M), Hz, ascending, (n,).

    Negative eigenvalues (an indefinite K, e.g. round-off on rigid-body modes) give negative
    frequencies, ``sign(lam) sqrt(|lam|) / 2 pi``, so that they stay visible.
    """
    lam = sla.eigh(np.asarray(K, dtype=float), np.asarray(M, dtype=float), eigvals_only=True)
    return np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi)


def reduce_by_transform(A: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``T^T A T`` (Eq. 4.1), symmetrised to remove round-off asymmetry, (n_a, n_a)."""
    B = T.T @ np.asarray(A, dtype=float) @ T
    return (B + B.T) / 2


def _solve_partition(A: np.ndarray, B: np.ndarray, name: str) -> np.ndarray:
    """``A^-1 B`` for a symmetric partition ``A``; a clear error when it is singular."""
    if A.size and np.linalg.cond(A) > _COND_MAX:
        raise InputError(
            f"{name} is singular: the retained DOFs do not hold every motion of the omitted "
            "DOFs (retain at least one DOF of each free part, or ground the model)"
        )
    return sla.solve(A, B, assume_a="sym") if A.size else np.zeros_like(B)


# ----------------------------------------------------------------------------------------------
# Guyan (static) reduction
# ----------------------------------------------------------------------------------------------


def guyan_transform(K: np.ndarray, retained: Sequence[int]) -> np.ndarray:
    """Static (Guyan) transformation, Eqs. 4.3-4.4.

    ``x_o = -K_oo^-1 K_oa x_a``: column ``r`` is the static shape with a unit displacement at
    retained DOF ``r`` and none at the others (a constraint mode).

    Parameters
    ----------
    K : (n, n)
        Stiffness of the full model.
    retained : sequence of int, (n_a,)
        Retained (measured) DOF indices, in the order of the TAM's DOFs.

    Returns
    -------
    T : (n, n_a)
        Identity at the retained rows.
    """
    K = np.asarray(K, dtype=float)
    a = index_array(retained, K.shape[0])
    o = omitted_indices(K.shape[0], a)
    T = np.zeros((K.shape[0], a.size))
    T[a, np.arange(a.size)] = 1.0
    T[o] = -_solve_partition(K[np.ix_(o, o)], K[np.ix_(o, a)], "K_oo")
    return T


def guyan_reduce(M: np.ndarray, K: np.ndarray, retained: Sequence[int]) -> ReducedModel:
    """Guyan TAM (Eqs. 4.2-4.4): exact when the omitted DOFs carry no mass.

    Parameters
    ----------
    M, K : (n, n)
    retained : sequence of int, (n_a,)

    Returns
    -------
    ReducedModel
        ``M_a``, ``K_a`` (n_a, n_a) and ``T`` (n, n_a).

    Raises
    ------
    InputError
        M or K not real, finite, square, of one size and symmetric
        (:func:`ssid.model_checks.model_matrices`); retained indices that are not distinct DOF
        indices (:func:`ssid.model_checks.index_array`); K_oo singular.
    """
    M, K = model_matrices(M, K)
    T = guyan_transform(K, retained)
    return ReducedModel(reduce_by_transform(M, T), reduce_by_transform(K, T), T)


# ----------------------------------------------------------------------------------------------
# IRS (improved reduced system)
# ----------------------------------------------------------------------------------------------


def irs_transform(M: np.ndarray, K: np.ndarray, retained: Sequence[int]) -> np.ndarray:
    """O'Callahan's IRS transformation, Eqs. 4.5-4.6 (corrected).

    ``T_IRS = T_s + S M T_s M_s^-1 K_s`` with ``S`` the flexibility of the omitted DOFs with
    the retained ones fixed (``K_oo^-1`` in the o-rows, zero elsewhere), ``M_s``, ``K_s`` the
    Guyan matrices. The omitted DOFs' inertia force ``-omega^2 (M_oo x_o + M_oa x_a)`` is
    estimated with the Guyan shapes and Guyan frequencies, ``omega^2 x_a ~ M_s^-1 K_s x_a``,
    and applied statically.

    Notes
    -----
    The report prints ``K_oo^-1 [M_oo + M_oo T_static]`` and an identity in the a-rows of
    ``T_dynamic``. Dimensionally the bracket must be the o-rows of ``M T_static``, i.e.
    ``[M_oo  M_oa] T_static``, and the a-rows of ``T_dynamic`` must be zero, or ``T_IRS``
    would not keep ``x_a = x_a``.

    Returns
    -------
    T : (n, n_a)
    """
    M, K = model_matrices(M, K)
    a = index_array(retained, K.shape[0])
    o = omitted_indices(K.shape[0], a)
    Ts = guyan_transform(K, a)
    Ms = reduce_by_transform(M, Ts)
    Ks = reduce_by_transform(K, Ts)
    # omega^2 of the Guyan model acting on x_a. M_s is positive definite whenever M is; with
    # massless DOFs it is singular when a retained one drags no mass statically (a massless DOF
    # whose neighbours are all retained), and IRS has no Guyan frequencies to work with.
    w, V = np.linalg.eigh(Ms)
    null = np.abs(V[:, w <= w[-1] / _COND_MAX])
    if null.size:
        k = np.flatnonzero(null.max(axis=1) > 0.5 * null.max())
        raise InputError(
            f"the Guyan mass M_s is singular: retained DOF {', '.join(f'no. {i + 1} (model index {a[i]})' for i in k)} "
            "moves no mass, nor do the omitted DOFs it drags statically (a massless DOF whose neighbours are "
            "retained); IRS estimates the omitted inertia with the Guyan frequencies M_s^-1 K_s, which a singular "
            "M_s does not have: use Guyan (exact for massless omitted DOFs), or retain a DOF with mass")
    dyn = sla.solve(Ms, Ks, assume_a="sym")
    inertia = (M @ Ts)[o] @ dyn  # (n_o, n_a): o-rows of M T_s M_s^-1 K_s
    T = Ts.copy()
    T[o] += _solve_partition(K[np.ix_(o, o)], inertia, "K_oo")
    return T


def irs_reduce(M: np.ndarray, K: np.ndarray, retained: Sequence[int]) -> ReducedModel:
    """IRS TAM (Eqs. 4.5-4.6): Guyan plus a static estimate of the omitted inertia.

    Equal to Guyan when the omitted DOFs are massless; closer to the full model's lower
    frequencies otherwise (and never below them: it is a Ritz reduction).
    """
    T = irs_transform(M, K, retained)
    return ReducedModel(reduce_by_transform(M, T), reduce_by_transform(K, T), T)


# ----------------------------------------------------------------------------------------------
# SEREP / modal TAM and the hybrid TAM
# ----------------------------------------------------------------------------------------------


def _target_modes(
    M: np.ndarray, K: np.ndarray, targets: Sequence[int] | None, n_default: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass-normalised full-model modes at 0-based ``targets`` (default: the lowest n), and
    their 1-based mode numbers (for messages); the finite modes when M has massless DOFs."""
    lam, phi = normal_modes_semidefinite(M, K)
    t = np.arange(n_default) if targets is None else np.asarray(targets, dtype=int)
    if t.size == 0 or t.min() < 0 or t.max() >= lam.size or np.unique(t).size != t.size:
        raise InputError(f"target modes must be distinct mode numbers between 1 and {lam.size}")
    return lam[t], phi[:, t], t + 1


def retained_share(phi: np.ndarray, retained: Sequence[int]) -> np.ndarray:
    """Each mode's norm over the retained DOFs relative to its norm over the whole model,
    (n_modes,) in [0, 1]: 0 for a mode at rest at every retained DOF (0 too for a zero mode).

    Scale-free per mode. A share at or below 1e-8 is round-off: the retained DOFs do not
    observe that mode (:func:`serep_transform` refuses it as a target; a correlation gives it
    MAC 0 rather than the MAC of its round-off, scaled up to unit length).
    """
    phi = np.asarray(phi, dtype=float)
    size = np.linalg.norm(phi, axis=0)
    return np.linalg.norm(phi[np.asarray(retained, dtype=int)], axis=0) / np.where(size > 0, size, 1.0)


def serep_transform(
    phi_t: np.ndarray, retained: Sequence[int], mode_numbers: Sequence[int] | None = None
) -> np.ndarray:
    """Modal (SEREP) transformation ``T = Phi_t Phi_ta^g``, Eqs. 4.7-4.8.

    Parameters
    ----------
    phi_t : (n, n_t)
        Target modes (any scaling: ``T`` does not depend on it).
    retained : sequence of int, (n_a,), with ``n_a >= n_t``
    mode_numbers : sequence of int, (n_t,), optional
        1-based full-model numbers of the target modes, to name them in an error (default:
        their columns in ``phi_t``).

    Returns
    -------
    T : (n, n_a)
        Reproduces every target mode exactly from its retained partition.

    Raises
    ------
    InputError
        More target modes than retained DOFs; a target mode not observable at the retained
        DOFs; target modes not independent there.

    Notes
    -----
    The generalised inverse ``(Phi_ta^T Phi_ta)^-1 Phi_ta^T`` of Eq. 4.8 is computed by a
    least-squares solve, which does not square the condition number as the normal equations do.

    The retained partition is judged with each mode scaled to unit norm over the full model,
    not relative to its own largest singular value: a target mode with a node at every retained
    DOF has a partition of round-off (1e-16 of the mode), and when every target is such a mode
    all singular values are round-off alike, their ratio near 1, and ``T`` (~1e16) and the TAM
    mass (~1e32) garbage.
    """
    phi_t = np.asarray(phi_t, dtype=float)
    a = index_array(retained, phi_t.shape[0])
    phi_ta = phi_t[a]
    if phi_t.shape[1] > a.size:
        raise InputError(
            f"{phi_t.shape[1]} target modes but only {a.size} retained DOFs: SEREP needs at "
            "most as many target modes as retained DOFs"
        )
    seen = retained_share(phi_t, a)
    blind = np.flatnonzero(seen <= _MODE_RCOND)
    if blind.size:
        names = (np.arange(1, phi_t.shape[1] + 1) if mode_numbers is None
                 else np.asarray(mode_numbers, dtype=int))[blind]
        one = blind.size == 1
        what = ("target mode" if one else "target modes") + ("" if mode_numbers is not None else
                                                             " (columns of phi_t)")
        raise InputError(
            f"{what} {', '.join(str(k) for k in names)} {'is' if one else 'are'} not observable at "
            f"the retained DOFs: {'its' if one else 'their'} motion there is "
            f"{'' if one else 'at most '}{seen[blind].max():.1g} of {'its' if one else 'their'} "
            "norm over the model (a node at every retained DOF); retain a DOF where "
            f"{'it moves' if one else 'each moves'}, or choose other target modes"
        )
    s = np.linalg.svd(phi_ta / np.linalg.norm(phi_t, axis=0), compute_uv=False)
    if s[-1] <= _MODE_RCOND:
        raise InputError(
            "the target modes are not linearly independent at the retained DOFs "
            "(choose other retained DOFs or target modes)"
        )
    pinv = np.linalg.lstsq(phi_ta, np.eye(a.size), rcond=None)[0]  # (n_t, n_a), Eq. 4.8
    return phi_t @ pinv


def serep_reduce(
    M: np.ndarray, K: np.ndarray, retained: Sequence[int], targets: Sequence[int] | None = None
) -> ReducedModel:
    """SEREP / modal TAM (Eqs. 4.7-4.8).

    Parameters
    ----------
    M, K : (n, n)
    retained : sequence of int, (n_a,)
    targets : sequence of int, optional
        0-based numbers of the target modes (ascending-frequency order of the full model);
        default: the lowest ``n_a`` modes.

    Returns
    -------
    ReducedModel
        With ``n_t = n_a`` the TAM's frequencies and modes are the target modes' exactly.
        With fewer target modes ``M_a`` and ``K_a`` have rank ``n_t`` only (use
        :func:`hybrid_tam` for a full-rank TAM that still keeps the targets exact).
    """
    # The model and the DOFs first: with no retained DOF the default targets would be none,
    # and the message about them.
    M, K = model_matrices(M, K)
    retained = index_array(retained, K.shape[0])
    _, phi_t, numbers = _target_modes(M, K, targets, len(retained))
    T = serep_transform(phi_t, retained, numbers)
    return ReducedModel(reduce_by_transform(M, T), reduce_by_transform(K, T), T)


def hybrid_transform(
    M: np.ndarray, K: np.ndarray, retained: Sequence[int], phi_t: np.ndarray,
    mode_numbers: Sequence[int] | None = None,
) -> np.ndarray:
    """Kammer's hybrid TAM transformation, Eqs. 4.9-4.10.

    ``T_h = T_s + (T_m - T_s) P`` with the oblique projector ``P = Phi_ta Phi_ta^T M_m``
    (n_a, n_a) onto the target modes' retained partitions, ``M_m = T_m^T M T_m`` the SEREP mass
    and ``Phi_t`` mass-normalised in the full model (then ``Phi_ta^T M_m Phi_ta = I``).
    ``T_h Phi_ta = Phi_t``: the target modes are kept exactly; along the complementary
    (residual) directions ``T_h`` is the static ``T_s``.

    Parameters
    ----------
    M, K : (n, n)
    retained : sequence of int, (n_a,)
    phi_t : (n, n_t)
        Target modes, any scaling (they are mass-normalised here).
    mode_numbers : sequence of int, (n_t,), optional
        Their 1-based full-model numbers, for messages (:func:`serep_transform`).

    Returns
    -------
    T : (n, n_a)
    """
    M, K = model_matrices(M, K)
    a = index_array(retained, K.shape[0])
    phi_t = np.asarray(phi_t, dtype=float)
    # Eq. 4.9 needs unit modal mass; rescaling here makes the result scaling-free.
    phi_t = phi_t / np.sqrt(np.einsum("ij,ik,kj->j", phi_t, M, phi_t))
    Ts = guyan_transform(K, a)
    Tm = serep_transform(phi_t, a, mode_numbers)
    Mm = reduce_by_transform(M, Tm)
    phi_ta = phi_t[a]
    P = phi_ta @ (phi_ta.T @ Mm)  # Eq. 4.9
    return Ts + (Tm - Ts) @ P  # Eq. 4.10


def hybrid_tam(
    M: np.ndarray, K: np.ndarray, retained: Sequence[int], targets: Sequence[int] | None = None
) -> ReducedModel:
    """Hybrid TAM (Eqs. 4.9-4.10): the target modes exact, the rest static.

    Parameters
    ----------
    targets : sequence of int, optional
        0-based numbers of the target modes; default: the lowest ``n_a`` (then the hybrid
        TAM equals SEREP, since ``P = I``). Give fewer to gain Guyan's robustness for the
        residual modes, but keep a free structure's rigid-body modes among them: Guyan holds a
        rigid motion ``r`` exactly, yet ``P r_a`` (the least-squares fit of ``r_a`` by the
        targets' partitions) is not zero, so ``T_h r_a`` adds the targets' elastic difference
        from their static shapes, with strain energy: rigid-body modes moved to 0.97 and 8.0 Hz
        on a free beam with elastic targets only.
    """
    # The model and the DOFs first: with no retained DOF the default targets would be none,
    # and the message about them.
    M, K = model_matrices(M, K)
    retained = index_array(retained, K.shape[0])
    _, phi_t, numbers = _target_modes(M, K, targets, len(retained))
    T = hybrid_transform(M, K, retained, phi_t, numbers)
    return ReducedModel(reduce_by_transform(M, T), reduce_by_transform(K, T), T)


# ----------------------------------------------------------------------------------------------
# Dispatcher
# ----------------------------------------------------------------------------------------------


def reduce_to_tam(
    method: str,
    M: np.ndarray,
    K: np.ndarray,
    retained: Sequence[int],
    *,
    targets: Sequence[int] | None = None,
    boundary: Sequence[int] | None = None,
) -> ReducedModel:
    """Any TAM by name; ``T``'s columns follow ``retained``.

    Parameters
    ----------
    method : {"guyan", "irs", "serep", "hybrid", "cb"}
    M, K : (n, n)
    retained : sequence of int, (n_a,)
    targets : sequence of int, optional
        0-based target mode numbers (serep, hybrid, and the fixed-interface mode selection of
        cb); default the lowest ``n_a``.
    boundary : sequence of int, optional
        Interface DOFs (cb only; each must be retained).
    """
    if method == "guyan":
        return guyan_reduce(M, K, retained)
    if method == "irs":
        return irs_reduce(M, K, retained)
    if method == "serep":
        return serep_reduce(M, K, retained, targets)
    if method == "hybrid":
        return hybrid_tam(M, K, retained, targets)
    if method == "cb":
        from .craig_bampton_tam import craig_bampton_tam

        return craig_bampton_tam(M, K, retained, boundary, targets=targets).reduced
    raise InputError(f"unknown TAM {method!r}; choose one of {', '.join(TAM_METHODS)}")
