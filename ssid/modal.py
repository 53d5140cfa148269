"""Modal quantities of an identified model and physical-consistency checks.

Natural frequency and damping of a complex root (Eqs. 5.18-5.19), modal phase collinearity
(Eqs. 5.20-5.23), real normal modes, the "modal" damping matrix of section 6.2.3, and the
checks that flag a result that is not physical (asymmetry, indefinite M or K, negative damping).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .errors import InputError

#: Why no modal damping matrix can be built on a model: said where one stands in for its C.
MODAL_DAMPING_NEEDS_MASS = ("M is not positive definite (a DOF without mass?), and modal damping, which stands "
                            "in for a model without C, needs a mass at every DOF: give the model its C")

__all__ = [
    "root_frequency_damping",
    "modal_phase_collinearity",
    "real_modes",
    "modal_damping_matrix",
    "physical_checks",
    "complex_modes",
    "companion_matrix",
    "unit_max_shapes",
]


def root_frequency_damping(lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequency (rad/s) and damping ratio of complex roots (Eqs. 5.18-5.19).

    ``zeta = -Re(lambda)/|lambda|`` and ``omega = Im(lambda)/sqrt(1 - zeta^2) = |lambda|``.
    """
    lam = np.asarray(lam)
    wn = np.abs(lam)
    zeta = -lam.real / np.where(wn > 0, wn, 1.0)
    return wn, zeta


def unit_max_shapes(phi: np.ndarray) -> np.ndarray:
    """Mode shapes (n, m), real or complex, each divided by its largest-magnitude entry (which
    becomes 1): the normalisation of identified shapes in results and files."""
    phi = np.asarray(phi)
    if phi.shape[1] == 0:
        return phi.copy()
    return phi / phi[np.argmax(np.abs(phi), axis=0), np.arange(phi.shape[1])]


def modal_phase_collinearity(phi: np.ndarray) -> np.ndarray:
    """Modal phase collinearity of complex mode shapes (Juang and Pappa; Eqs. 5.20-5.23).

    Parameters
    ----------
    phi : (n, m) complex
        Mode shapes in columns.

    Returns
    -------
    (m,) float in [0, 1]; 1 for a mode whose coefficients are all in phase (a normal mode).

    Notes
    -----
    The report's formula is evaluated in its equivalent, singularity-free form: MPC is
    ``((l1 - l2)/(l1 + l2))^2`` with ``l1, l2`` the eigenvalues of the 2x2 covariance of the
    centred real and imaginary parts (Eq. 5.21 centring). Eq. 5.22 divides by
    ``Re^T Im``, which is zero for an exactly real mode; this form is not.
    """
    phi = np.atleast_2d(np.asarray(phi, dtype=complex))
    t = phi - phi.mean(axis=0, keepdims=True)  # Eq. 5.21
    xr, xi = t.real, t.imag
    srr = np.sum(xr * xr, axis=0)
    sii = np.sum(xi * xi, axis=0)
    sri = np.sum(xr * xi, axis=0)
    tr = srr + sii
    disc = np.sqrt((srr - sii) ** 2 + 4 * sri**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mpc = np.where(tr > 0, (disc / tr) ** 2, 1.0)
    return np.clip(mpc, 0.0, 1.0)


def real_modes(M: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undamped natural frequencies (rad/s, ascending) and mass-normalised modes of (K, M).

    Raises ``numpy.linalg.LinAlgError`` when M is not positive definite.
    """
    eigval, phi = sla.eigh(K, M)
    wn = np.sqrt(np.abs(eigval)) * np.sign(eigval)
    return wn, phi


def companion_matrix(C_hat: np.ndarray, K_hat: np.ndarray) -> np.ndarray:
    """``[[0, I], [-K^, -C^]]`` (2n, 2n): the state matrix of ``x'' + C^ x' + K^ x = 0`` with
    ``C^ = M^-1 C``, ``K^ = M^-1 K``, i.e. ``-A^_s^-1 B^_s`` of Eqs. 3.11-3.12. Its eigenvalues
    are the roots lambda_r, its eigenvectors ``[phi; lambda phi]``."""
    n = C_hat.shape[0]
    return np.block([[np.zeros((n, n)), np.eye(n)], [-K_hat, -C_hat]])


def complex_modes(M: np.ndarray, C: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Complex roots with Im > 0 (ascending |lambda|) and their displacement shapes (n, m)."""
    n = M.shape[0]
    lam, V = np.linalg.eig(companion_matrix(np.linalg.solve(M, C), np.linalg.solve(M, K)))
    keep = np.flatnonzero(lam.imag > 1e-10 * np.abs(lam).max())
    keep = keep[np.argsort(np.abs(lam[keep]))]
    return lam[keep], V[:n, keep]


def modal_damping_matrix(M: np.ndarray, K: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Viscous damping matrix with given modal damping ratios (section 6.2.3, "modal" C).

    ``C = M Phi diag(2 zeta_r omega_r) Phi^T M`` with ``Phi`` the mass-normalised real modes,
    ``zeta`` in the order of ascending undamped frequency (missing ratios: the last one given).

    Raises
    ------
    InputError
        M is not positive definite (:data:`MODAL_DAMPING_NEEDS_MASS`): the modes whose
        ratios are given need a mass at every DOF.
    """
    try:
        wn, phi = real_modes(M, K)
    except np.linalg.LinAlgError:
        raise InputError(MODAL_DAMPING_NEEDS_MASS) from None
    z = np.asarray(zeta, dtype=float)
    if z.size < wn.size:
        z = np.concatenate([z, np.full(wn.size - z.size, z[-1] if z.size else 0.0)])
    Mphi = M @ phi
    C = Mphi @ np.diag(2 * z[: wn.size] * np.abs(wn)) @ Mphi.T
    return (C + C.T) / 2


def physical_checks(M: np.ndarray, C: np.ndarray, K: np.ndarray, zeta: np.ndarray) -> tuple[dict, list[str]]:
    """Checks of an identified model; returns (numbers, warnings for anything not physical).

    Symmetry (relative Frobenius norm of the skew part), definiteness of M and K (smallest
    eigenvalue relative to the largest), negative modal damping and negative eigenvalues of C.
    """
    checks: dict = {}
    warnings: list[str] = []
    for name, A in (("M", M), ("C", C), ("K", K)):
        nrm = np.linalg.norm(A)
        checks[f"{name}_asymmetry"] = float(np.linalg.norm(A - A.T) / nrm) if nrm > 0 else 0.0
        ev = np.linalg.eigvalsh((A + A.T) / 2)
        top = np.max(np.abs(ev)) if ev.size else 0.0
        checks[f"{name}_min_eig_rel"] = float(ev.min() / top) if top > 0 else 0.0
    if checks["M_min_eig_rel"] <= 0:
        warnings.append("identified M is not positive definite: the model is not physical")
    if checks["K_min_eig_rel"] < -1e-9:
        warnings.append("identified K is not positive semi-definite: the model is not physical")
    if checks["C_min_eig_rel"] < -1e-9:
        warnings.append("identified C has negative eigenvalues (some motions gain energy)")
    zeta = np.asarray(zeta)
    neg = np.flatnonzero(zeta < 0)
    checks["n_negative_damping"] = int(neg.size)
    if neg.size:
        warnings.append(f"{neg.size} mode(s) with negative damping: {', '.join(str(i + 1) for i in neg)}")
    return checks, warnings
