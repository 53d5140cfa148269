"""Normal modes of a model whose mass matrix is positive semi-definite (massless DOFs).

A lumped-mass FE model often gives its rotations no inertia: ``M`` is singular, and
``scipy.linalg.eigh(K, M)`` (a Cholesky factor of ``M``) refuses it, though the model has a
finite mode for each massless-free direction and the rest at infinite frequency. The massless
coordinates carry no inertia force, so at any frequency they follow the others statically:
condensing them out (Guyan on the null space of ``M``) is exact for the finite modes, and
expanding gives their shapes at every DOF.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .model_checks import MassNotPositiveDefinite, model_matrices

__all__ = ["MASSLESS_RTOL", "largest_entry_positive", "normal_modes_semidefinite"]

#: An eigenvalue of M at most this fraction of its largest is no mass: eigvalsh gives M's
#: eigenvalues to about n eps of the largest (1e-13 at 500 DOFs), a zero mass as round-off of
#: that size, and a physical mass, rotary inertia in kg m^2 beside kg included, lies decades above.
MASSLESS_RTOL = 1e-12
# The massless part of K, inverted, is treated as singular beyond this condition number, as
# ssid.tam does with its partitions: a solve would lose every significant digit.
_COND_MAX = 1e13


def normal_modes_semidefinite(M: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``omega^2`` (rad^2/s^2, ascending) and mass-normalised modes of (K, M) for a
    symmetric ``M`` that is positive semi-definite.

    With ``M`` positive definite this is :func:`ssid.tam.normal_modes`. Otherwise, with
    ``M = [R N] diag(m_r, 0) [R N]^T`` (``N`` the eigenvectors of ``M`` at zero), the massless
    coordinates ``z`` follow ``y`` statically, ``z = -K_nn^-1 K_nr y``, and the finite modes
    are those of ``(T^T K T, T^T M T)`` with ``T = R - N K_nn^-1 K_nr``, expanded by ``T``.
    Exact: the finite eigenvalues are those of the generalised problem (scipy.linalg.eig's).

    Parameters
    ----------
    M, K : (n, n)
        Mass (kg) and stiffness (N/m); real, finite, symmetric.

    Returns
    -------
    lam : (r,)
        The finite eigenvalues, ``r`` the rank of ``M``.
    phi : (n, r)
        ``phi^T M phi = I``; each column's largest-magnitude entry positive.

    Raises
    ------
    MassNotPositiveDefinite
        ``M`` has a negative eigenvalue (beyond round-off) or is zero: no normal modes; or the
        massless coordinates are not held by ``K`` (a massless mechanism, whose motion no
        equation fixes). An InputError, and a ``numpy.linalg.LinAlgError`` for callers that
        name the model in their own message.
    InputError
        M or K not finite, square, of one size or symmetric.
    """
    M, K = model_matrices(M, K)
    # M's own eigenvalues decide, not whether a Cholesky factor exists: round-off lets one
    # through on a singular M whose null space is not along the coordinates (lumped masses
    # with an offset couple a translation and a rotation), and eigh(K, M) then returned
    # -1853 and -1175 Hz for modes of 7.4 and 17.5 Hz.
    mu, V = np.linalg.eigh(M)
    tol = MASSLESS_RTOL * max(float(np.max(np.abs(mu))), 0.0)
    if mu[0] > tol:
        try:
            return largest_entry_positive(*sla.eigh(K, M))
        except np.linalg.LinAlgError:
            pass
    if not np.any(mu > tol):
        raise MassNotPositiveDefinite("M is zero: (K, M) has no normal modes")
    if mu[0] < -tol:
        raise MassNotPositiveDefinite(f"M is not positive semi-definite (an eigenvalue of {mu[0]:.3g}, "
                                      "a negative mass): (K, M) has no normal modes")
    R, N = V[:, mu > tol], V[:, mu <= tol]
    if not N.shape[1]:  # (a Cholesky factor failed on an M above the bar: in M's own basis)
        lam, psi = sla.eigh(R.T @ K @ R, np.diag(mu))
        return largest_entry_positive(lam, R @ psi)
    Knn = N.T @ K @ N
    if np.linalg.cond(Knn) > _COND_MAX:
        raise MassNotPositiveDefinite(
            f"M has {N.shape[1]} massless direction(s) that K does not hold (K is singular on them: a "
            "massless mechanism, whose motion nothing fixes): (K, M) has no normal modes")
    T = R - N @ sla.solve(Knn, N.T @ K @ R, assume_a="sym")
    Kr, Mr = T.T @ K @ T, T.T @ M @ T
    lam, psi = sla.eigh((Kr + Kr.T) / 2, (Mr + Mr.T) / 2)
    return largest_entry_positive(lam, T @ psi)


def largest_entry_positive(lam: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each mode with its largest-magnitude entry positive, so that the sign of a mode does
    not flip between runs (:func:`ssid.tam.normal_modes` too)."""
    big = np.argmax(np.abs(phi), axis=0)
    return lam, phi * np.sign(phi[big, np.arange(phi.shape[1])])

