"""M, C, K of a modal model whose modes are real normal modes (report Eq. 3.26, section 6.2.3).

Band processing (:mod:`ssid.band_scaling`), its completions below and above the band
(:mod:`ssid.band_select`) and pseudo-DOF step 2 (:mod:`ssid.pseudo_dof_step2`) all end with n
real shapes at n DOFs, a modal mass, a natural frequency and a damping ratio per mode, and
build M, C, K from them here, in one way: through the inverse of the shape matrix,

    M = Phi^-T diag(m) Phi^-1,  C = Phi^-T diag(2 zeta omega m) Phi^-1,
    K = Phi^-T diag(omega^2 m) Phi^-1,

which holds rigid-body modes (omega = 0: K singular, as a free structure's is) as well as
elastic ones, and gives eig(K, M) = omega^2 exactly whatever the modal masses.
"""

from __future__ import annotations

import numpy as np

from .errors import IdentificationError

__all__ = ["normal_mode_mck", "normal_mode_shapes", "real_mode_mck", "shapes_independent"]


def real_mode_mck(phi: np.ndarray, inv_m: np.ndarray, omega_n: np.ndarray,
                  zeta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K (n, n) with the real normal modes ``phi`` (n, n), modal damping.

    ``phi^T M phi = diag(m)``, ``phi^T K phi = diag(omega_n^2 m)``, ``phi^T C phi =
    diag(2 zeta omega_n m)``; so ``M^-1 = phi diag(1/m) phi^T`` is Eq. 3.26's (x', x')
    partition with X = 0 (:func:`normal_mode_mck`), and C is the modal damping of the
    report's section 6.2.3.

    Parameters
    ----------
    phi : (n, n) real shapes at the n DOFs, linearly independent (the caller checks how
        nearly: :func:`numpy.linalg.inv` only refuses an exactly singular matrix).
    inv_m : (n,) inverse modal masses ``1/m_r`` of those shapes; a mode with ``1/m_r <= 0``
        gives an M that is not positive definite, which the caller's physical checks report.
    omega_n : (n,) natural frequencies, rad/s (0 for a rigid-body mode).
    zeta : (n,) damping ratios.

    Returns
    -------
    (M, C, K), symmetric, in the units of ``phi`` and ``1/m`` (kg, N s/m, N/m for
    accelerance in (m/s^2)/N).
    """
    inv_m = np.asarray(inv_m, dtype=float)
    if np.any(inv_m == 0) or not np.all(np.isfinite(inv_m)):
        raise IdentificationError("a mode's inverse modal mass is 0 or not finite: its scale "
                                  "factor does not determine a modal mass")
    m = 1.0 / inv_m
    P = np.linalg.inv(phi)
    M, C, K = (P.T @ (d[:, None] * P) for d in (m, 2 * zeta * omega_n * m, omega_n**2 * m))
    # Symmetric by construction; remove rounding asymmetry only.
    return (M + M.T) / 2, (C + C.T) / 2, (K + K.T) / 2


def normal_mode_mck(lam: np.ndarray, theta_x: np.ndarray,
                    u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K (n, n) from n complex pairs taken as real normal modes.

    Eq. 3.26 gives ``A_s^-1 = Theta diag(u) Theta^T``, whose partitions are, with Eq. 3.15,
    ``X = Theta_x diag(u) Theta_x^T = 0``, ``M^-1 = Theta_x diag(u lambda) Theta_x^T`` and
    ``K^-1 = -Theta_x diag(u / lambda) Theta_x^T`` (sums over both members of each pair). M
    taken from the inverse of the whole ``Theta`` (:func:`ssid.step2.assemble_mck`) is
    ``(M^-1 + X K X)^-1``: a residue ``X`` of 1e-5 of ``M^-1`` (slightly complex shapes of noisy
    bands), multiplied by the stiffness of modes three decades above the lowest, makes M
    indefinite. For a lightly damped structure whose modes are normal (what criterion 3, MPC,
    checks), ``theta_r`` is a real shape ``phi_r`` times a phase and
    ``u_r = -j / (2 omega_dr m_r)``; then X = 0 exactly and

        M^-1 = Phi diag(1/m) Phi^T,  K^-1 = Phi diag(1/(m omega^2)) Phi^T,
        C = M Phi diag(2 zeta omega / m) Phi^T M      (modal damping, report section 6.2.3)

    with ``omega_r = |lambda_r|``, ``zeta_r`` of Eq. 5.18, assembled by :func:`real_mode_mck`.
    M and K are positive definite when every modal mass ``m_r > 0`` and the shapes are
    independent, and eig(K, M) = omega_r^2 exactly: the scale factors set the modal masses,
    not the frequencies.

    Parameters
    ----------
    lam : (n,) complex roots (Im > 0), rad/s.
    theta_x : (n, n) complex displacement shapes, any normalisation.
    u : (n,) complex ``1/a~_r`` for that normalisation (Eq. 3.23).

    Returns
    -------
    (M, C, K, m): m (n,) the modal masses of the real shapes ``phi_r`` (kg for unit-free
    shapes if H is in (m/s^2)/N); M, C, K in the units of Eq. 3.15.
    """
    lam = np.asarray(lam, dtype=complex)
    phi, inv_m = normal_mode_shapes(lam, theta_x, u)
    wn = np.abs(lam)
    M, C, K = real_mode_mck(phi, inv_m, wn, -lam.real / wn)
    return M, C, K, 1.0 / inv_m


def normal_mode_shapes(lam: np.ndarray, theta_x: np.ndarray,
                       u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Real shapes ``phi`` (n, m) and inverse modal masses ``1/m`` (m,) of complex pairs taken
    as real normal modes (see :func:`normal_mode_mck`): each shape turned by the phase that
    makes it most nearly real, ``u_r = -j / (2 omega_dr m_r)`` read for that phase."""
    lam = np.asarray(lam, dtype=complex)
    th = np.asarray(theta_x, dtype=complex)
    # Phase that makes each shape most nearly real: maximises |Re(e^{j a} theta)|^2 =
    # (|theta|^2 + Re(e^{2ja} theta^T theta)) / 2.
    alpha = -0.5 * np.angle(np.sum(th * th, axis=0))
    phi = (th * np.exp(1j * alpha)).real
    u_real = np.asarray(u) * np.exp(-2j * alpha)  # u theta theta^T = u_real phi phi^T (to the imag part)
    return phi, -2 * lam.imag * u_real.imag


def shapes_independent(shapes: np.ndarray, rtol: float = 1e-8) -> bool:
    """Whether the columns of ``shapes`` (n, m), real or complex, each normalised, are linearly
    independent to ``rtol`` (smallest over largest singular value), as Eq. 3.26's inverse
    (and :func:`real_mode_mck`'s) needs."""
    sv = np.linalg.svd(shapes / np.linalg.norm(shapes, axis=0), compute_uv=False)
    return bool(sv[-1] >= rtol * sv[0])
