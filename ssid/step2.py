"""SSID step 2: M, C, K from the step-1 matrices and the FRFs (Eqs. 3.10-3.26).

The state-space eigenproblem of Eq. 3.12 gives the complex modes; Eq. 3.23 fits their modal
scale factors 1/a~_r to the measured accelerances; Eq. 3.26 then rebuilds the symmetric state
matrices A_s, B_s of Eq. 3.15 whose partitions are M, C and K.

Two things differ from the report's MATLAB listing, on purpose:

* Conjugate modes get conjugate scale factors. The listing solves ``E \\ Y`` with complex
  unknowns, so A_s comes out complex and only its real part is kept. We solve for the real and
  imaginary parts of one factor per pair, which makes A_s real by construction and halves the
  unknowns.
* Eq. 3.23 is never formed. Its matrix has (lines x outputs x inputs) rows and 2n columns; its
  normal matrix is ``(Theta_x^H diag(b) Theta_x) o (P^H diag(a) P)`` (Hadamard product) when the
  weights factor as ``a_kj b_i``, where ``P[kj, r] = R_kr theta_r^T (D_f e_j + D_r h_r,kj)``
  (Eqs. 3.19, 3.24). Weights that do not factor (blanked values, per-value variances) are
  split into a short sum of such products by an SVD, or, failing that, accumulated in chunks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import IdentificationError
from .step1 import Step1Data

__all__ = ["StateSpaceModes", "state_space_modes", "modal_scale_factors", "assemble_mck"]


@dataclass
class StateSpaceModes:
    """Complex modes of Eq. 3.12, ordered ``[upper pairs, their conjugates, real roots]``.

    Attributes
    ----------
    lam : (2n,) complex
        Eigenvalues lambda_r, rad/s. Oscillatory roots first (Im > 0, ascending |lambda|),
        then their conjugates in the same order, then real (overdamped) roots.
    theta : (2n, 2n) complex
        Eigenvectors ``[phi; lambda phi]``, columns in the order of ``lam``.
    n_pairs : int
        Number of complex-conjugate pairs.
    """

    lam: np.ndarray
    theta: np.ndarray
    n_pairs: int

    @property
    def n(self) -> int:
        return self.theta.shape[0] // 2

    @property
    def theta_x(self) -> np.ndarray:
        """Displacement partition of the eigenvectors, (n, 2n)."""
        return self.theta[: self.n]


def state_space_modes(C_hat: np.ndarray, K_hat: np.ndarray) -> StateSpaceModes:
    """Solve ``(lambda A^_s + B^_s) theta = 0`` (Eqs. 3.11-3.12).

    ``A^_s`` is always invertible, and ``-A^_s^-1 B^_s = [[0, I], [-K^, -C^]]``, so the
    generalised problem is the standard eigenproblem of that companion matrix.
    """
    n = C_hat.shape[0]
    comp = np.block([[np.zeros((n, n)), np.eye(n)], [-K_hat, -C_hat]])
    lam, V = np.linalg.eig(comp)
    scale = np.max(np.abs(lam)) if lam.size else 1.0
    is_real = np.abs(lam.imag) <= 1e-10 * max(scale, 1e-300)
    upper = np.flatnonzero(~is_real & (lam.imag > 0))
    upper = upper[np.argsort(np.abs(lam[upper]))]
    n_lower = int(np.count_nonzero(~is_real & (lam.imag < 0)))
    if n_lower != upper.size:
        raise IdentificationError("state-space eigenvalues do not come in conjugate pairs")
    real = np.flatnonzero(is_real)
    real = real[np.argsort(np.abs(lam[real]))]
    V_up = V[:, upper]
    # Real roots have real eigenvectors; remove the arbitrary phase eig() may leave on them.
    V_re = V[:, real]
    if real.size:
        phase = np.exp(-1j * np.angle(V_re[np.argmax(np.abs(V_re), axis=0), np.arange(real.size)]))
        V_re = (V_re * phase).real.astype(complex)
    lam_all = np.concatenate([lam[upper], lam[upper].conj(), lam[real].real.astype(complex)])
    theta = np.hstack([V_up, V_up.conj(), V_re])
    return StateSpaceModes(lam=lam_all, theta=theta, n_pairs=int(upper.size))


def _factor_weights(w2: np.ndarray, max_terms: int = 4) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Write ``w2[kj, i]`` as ``sum_t a_t[kj] b_t[i]`` with few terms, or return None."""
    if np.all(w2 == w2[:1]):  # same weight profile over outputs in every column
        return [(np.ones(w2.shape[0]), w2[0])]
    col = w2[:, :1]
    if np.all(col > 0) and np.allclose(w2 / col, w2[:1] / col[:1], rtol=1e-12, atol=0):
        return [(col[:, 0], w2[0] / col[0, 0])]
    U, s, Vt = np.linalg.svd(w2, full_matrices=False)
    rank = int(np.count_nonzero(s > 1e-13 * s[0])) if s.size and s[0] > 0 else 0
    if rank == 0 or rank > max_terms:
        return None
    return [(U[:, t] * s[t], Vt[t]) for t in range(rank)]


def modal_scale_factors(d: Step1Data, modes: StateSpaceModes) -> np.ndarray:
    """Weighted least-squares estimate of ``1/a~_r`` from Eq. 3.23.

    Parameters
    ----------
    d : Step1Data
        Measured accelerances ``H`` (L, n, n_in), reactions ``Hr`` and weights ``1/sigma``.
    modes : StateSpaceModes

    Returns
    -------
    u : (2n,) complex
        ``1/a~_r``, with ``u`` of a conjugate mode equal to the conjugate of its partner's.
    """
    theta_x = modes.theta_x
    n, ns = theta_x.shape
    lam = modes.lam
    w = d.omega[:, None]
    R = -(w**2) / (1j * w - lam[None, :])  # Eq. 3.19, (L, ns)
    # q_kjr = theta_r^T (D_f e_j + D_r h_r,kj) of Eq. 3.24, (L, n_in, ns)
    q = np.broadcast_to(theta_x[d.in_idx][None], (d.omega.size, d.n_in, ns))
    if d.n_r:
        q = q + np.einsum("mr,kmj->kjr", theta_x[d.r_idx], d.Hr)
    P = (R[:, None, :] * q).reshape(-1, ns)  # rows (k, j)
    Hkj = np.swapaxes(d.H, 1, 2).reshape(-1, n)  # (L n_in, n)
    w2 = (np.swapaxes(d.weight, 1, 2) ** 2).reshape(-1, n)

    # Right-hand side: sum_kj conj(P_kjr) (theta_x^H (w^2 o h_kj))_r
    rhs = np.sum(P.conj() * ((w2 * Hkj) @ theta_x.conj()), axis=0)
    terms = _factor_weights(w2)
    if terms is not None:
        N = np.zeros((ns, ns), dtype=complex)
        for a, b in terms:
            N += (theta_x.conj().T @ (b[:, None] * theta_x)) * (P.conj().T @ (a[:, None] * P))
    else:
        N = np.zeros((ns, ns), dtype=complex)
        chunk = max(1, 2**20 // (n * ns))
        for s in range(0, P.shape[0], chunk):
            Y = P[s : s + chunk, None, :] * theta_x[None, :, :]  # (c, n, ns)
            Yw = Y * np.sqrt(w2[s : s + chunk])[:, :, None]
            Y2 = Yw.reshape(-1, ns)
            N += Y2.conj().T @ Y2

    # Real parametrisation u = T v: a pair shares (Re, Im); a real root has a real factor.
    m = modes.n_pairs
    T = np.zeros((ns, ns), dtype=complex)
    i = np.arange(m)
    T[i, i] = 1.0
    T[i, m + i] = 1j
    T[m + i, i] = 1.0
    T[m + i, m + i] = -1j
    j = np.arange(2 * m, ns)
    T[j, j] = 1.0
    Nr = (T.conj().T @ N @ T).real
    br = (T.conj().T @ rhs).real
    s = np.sqrt(np.abs(np.diag(Nr)))
    if np.any(s == 0):
        raise IdentificationError(
            "a mode has no valid data to fix its scale (Eq. 3.23): widen the band or add lines"
        )
    v = np.linalg.lstsq(Nr / s[:, None] / s[None, :], br / s, rcond=None)[0] / s
    return T @ v


def assemble_mck(
    modes: StateSpaceModes, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Rebuild M, C, K from the modes and their scale factors (Eqs. 3.25-3.26, 3.15).

    Returns
    -------
    (M, C, K, info): ``info`` holds the relative imaginary residue of A_s, B_s and the relative
    disagreement between the three copies of M in A_s and B_s (both ~0 for a consistent fit).
    """
    n = modes.n
    if np.any(u == 0) or not np.all(np.isfinite(u)):
        raise IdentificationError("a modal scale factor 1/a~_r is zero or not finite (Eq. 3.23)")
    a = 1.0 / u
    b = -modes.lam * a  # Eq. 3.25
    Ti = np.linalg.inv(modes.theta)
    As = Ti.T @ (a[:, None] * Ti)  # Eq. 3.26
    Bs = Ti.T @ (b[:, None] * Ti)
    M = -Bs[n:, n:].real
    C = As[:n, :n].real
    K = Bs[:n, :n].real
    scale = max(np.abs(As).max(), np.abs(Bs).max())
    info = {
        "imag_residue": float(max(np.abs(As.imag).max(), np.abs(Bs.imag).max()) / scale),
        "mass_copies_mismatch": float(
            max(np.abs(As[:n, n:].real - M).max(), np.abs(As[n:, :n].real - M).max())
            / max(np.abs(M).max(), 1e-300)
        ),
    }
    # A_s and B_s are symmetric by construction; remove rounding asymmetry only.
    return (M + M.T) / 2, (C + C.T) / 2, (K + K.T) / 2, info
