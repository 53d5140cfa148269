"""Solvers for over-determined linear systems ``A X ~ B`` (report section 5.1).

Least squares (Eq. 5.5), total least squares with several right-hand sides (Eqs. 5.7-5.14) and
its mixed form in which some columns of ``A`` are known exactly (they carry no noise, so TLS
must not perturb them). All are real-valued: SSID stacks real and imaginary parts before it
calls these.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

__all__ = ["solve_ls", "solve_tls", "column_scale", "power_of_two_near"]


def column_scale(A: np.ndarray) -> np.ndarray:
    """Euclidean norm of each column of ``A`` (1 where a column is zero), (n,)."""
    s = np.linalg.norm(A, axis=0)
    s[s == 0] = 1.0
    return s


def power_of_two_near(x: float) -> float:
    """The power of two nearest ``x`` in log scale (1 for 0 or a non-finite ``x``).

    Data divided by it stay clear of float64's ends when squared twice (weights ``1/var^2``,
    FRAC's fourth powers of |H|), and the division is exact: results on data that did not
    overflow are bit for bit those of the unscaled computation.
    """
    if not (np.isfinite(x) and x > 0):
        return 1.0
    return float(2.0 ** np.round(np.log2(x)))


def solve_ls(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Least-squares solution of ``A X ~ B`` (Eq. 5.5), through a QR-based solver.

    Columns of ``A`` are equilibrated first: the solution does not change, the conditioning
    does (SSID's columns span many decades: H/omega against H/omega^2).

    Parameters
    ----------
    A : (m, n) real
    B : (m, d) real

    Returns
    -------
    X : (n, d)
    """
    s = column_scale(A)
    X, *_ = sla.lstsq(A / s, B, lapack_driver="gelsy")
    return X / s[:, None]


def solve_tls(A: np.ndarray, B: np.ndarray, n_exact: int = 0) -> np.ndarray:
    """Total-least-squares solution of ``A X ~ B`` with ``d`` right-hand sides (Eqs. 5.7-5.14).

    The SVD of ``[A B] = U S V^T`` is partitioned as in Eq. 5.13 and ``X = -V12 V22^-1``
    (Eq. 5.14). With ``n_exact > 0`` the first ``n_exact`` columns of ``A`` are taken as
    noise-free (mixed LS-TLS, Van Huffel and Vandewalle): a QR factorisation removes them
    exactly, TLS is applied to the rest, and the exact part is recovered by back-substitution.
    The data are used as given: scaling them is the caller's choice (scaled TLS, section 5.1.3).

    Parameters
    ----------
    A : (m, n) real
    B : (m, d) real
    n_exact : int
        Number of leading columns of ``A`` that are known exactly.

    Returns
    -------
    X : (n, d)

    Raises
    ------
    numpy.linalg.LinAlgError
        When ``V22`` is singular (a "nongeneric" TLS problem).
    """
    m, n = A.shape
    d = B.shape[1]
    if n_exact == 0:
        _, _, Vt = np.linalg.svd(np.hstack([A, B]), full_matrices=False)
        V = Vt.T
        V12 = V[:n, n:]
        V22 = V[n:, n:]
        return -np.linalg.solve(V22.T, V12.T).T
    # Mixed LS-TLS: [A1 A2 B] = Q R; R11 is the exact block.
    n1 = n_exact
    _, R = np.linalg.qr(np.hstack([A, B]), mode="reduced")
    R11 = R[:n1, :n1]
    R12 = R[:n1, n1:n]
    R1b = R[:n1, n:]
    R22 = R[n1:, n1:n]
    R2b = R[n1:, n:]
    X2 = solve_tls(R22, R2b) if n > n1 else np.zeros((0, d))
    X1 = sla.solve_triangular(R11, R1b - R12 @ X2)
    return np.vstack([X1, X2])
