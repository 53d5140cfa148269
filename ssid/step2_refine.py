"""The written M, C, K refined by output error: the symmetric model closest to the data.

Step 2 (Eqs. 3.10-3.26) writes M, C, K from step 1's roots and their scale factors. Where
the band misses modes, the scale factors of the roots outside it are fixed only by the mass
line and the residual stiffness the band shows of them, and Eq. 3.26 cannot make A_s agree
with all of them at once: on the simulated free payload (9 of its 16 modes in 20-1500 Hz,
0.02 % noise, ``bench/free_test_noise.py``) the written model reproduced the data to
2.0-3.5 % while step 1's own (non-symmetric) model held them to the noise. Minimising the
weighted output error over the entries of M, C and K themselves, from the written model,
reached the noise level there in 15-25 steps, and took the matrices closer to the true ones
(M 4-9 % off to 1.3-4.3 %, K 4.6-7 % to 0.36-1.3 %). Where to try it, and whether to keep
what it gives, is :func:`ssid.identify.identify_mck`'s choice (docs/algorithm.md, step 2).

Written by hand rather than with ``scipy.optimize.least_squares``: its Jacobian would be
(values x 3 n(n+1)/2), 700 MB for a 16-DOF model over 2300 lines and three inputs; the
normal equations formed from (n^2 x n^2) products summed over lines (:func:`_normal_equations`)
take 5 such arrays, and a tenth of the time of forming them from the Jacobian.
"""

from __future__ import annotations

import numpy as np

from .frf import FRFData, applied_loads
from .step1_refine import _solve_scaled

__all__ = ["refine_mck_output_error"]

# Work-array entries per block of lines (complex, about 32 MB): lines at a time whose (n^2)
# products per input fit, for the sums of the normal equations.
_BLOCK_ENTRIES = 2_000_000


def _unpack(x: np.ndarray, n: int, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, C, K) from their scaled upper triangles ``x`` (3 n(n+1)/2,)."""
    iu = np.triu_indices(n)
    out = []
    for m, part in enumerate(np.split(x, 3)):
        A = np.zeros((n, n))
        A[iu] = part * scale[m]
        out.append(A + np.triu(A, 1).T)
    return out[0], out[1], out[2]


def _receptance(M: np.ndarray, C: np.ndarray, K: np.ndarray, omega: np.ndarray,
                loads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``G = Z^-1`` (l, n, n) and ``X = G F`` (l, n, n_in) at the lines ``omega``, with
    ``Z = K + i w C - w^2 M`` and ``F = loads`` (l, n, n_in) the forces each input applied."""
    w = omega[:, None, None]
    G = np.linalg.inv(K[None] + 1j * w * C[None] - w**2 * M[None])
    return G, G @ loads


def loads_on_outputs(frf: FRFData) -> tuple[np.ndarray, np.ndarray | None]:
    """The forces (n_freq, n_out, n_in) each input of ``frf`` applied over its outputs, and
    their variances (or None): :func:`ssid.frf.applied_loads` (the unit force at the input's
    DOF, plus the measured reactions at their DOFs, taken as known loads, Eq. 3.6) placed at
    the outputs, among which the load DOFs are."""
    loads = applied_loads(frf)
    rows = [list(frf.outputs).index(d) for d in loads.dofs]
    F = np.zeros((frf.n_freq, frf.n_out, frf.n_in), dtype=complex)
    F[:, rows, :] = loads.T
    if loads.var is None:
        return F, None
    var = np.zeros(F.shape)
    var[:, rows, :] = loads.var
    return F, var


def _weighted_residual(frf: FRFData, weight: np.ndarray, loads: np.ndarray,
                       M: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``w (H_model - H)`` over all lines, (L, n, n_in); 0 where ``w`` is."""
    _, X = _receptance(M, C, K, frf.omega, loads)
    Hm = -(frf.omega[:, None, None] ** 2) * X
    return np.where(weight > 0, weight * (Hm - np.where(weight > 0, frf.H, 0.0)), 0.0)


def _normal_equations(frf: FRFData, weight: np.ndarray, loads: np.ndarray, M: np.ndarray, C: np.ndarray,
                      K: np.ndarray, scale: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Re J^H J, Re J^H r)`` of the weighted residual ``r`` in the scaled upper triangles.

    With ``H = -w^2 Z^-1 F``, ``dH = w^2 G dZ X``; a symmetric entry p = (i, j) of a matrix moves
    ``Z`` by ``E_ij + E_ji`` times ``f = -w^2`` (M), ``i w`` (C) or 1 (K), so its column of the
    Jacobian is ``v w^2 f D_p`` with ``D_p = G[:, i] X[j] + G[:, j] X[i]`` (once on the diagonal)
    and ``v`` the weights. The products of two columns reduce to
    ``T[i, j, k, l] = sum_b Q_b[i, k] conj(X[j, b]) X[l, b]`` with ``Q_b = G^H diag(v_b^2) G``,
    summed over lines with the five powers of ``w`` that ``conj(f) f'`` takes: (n^2 x n^2)
    products, against (3 n(n+1)/2)^2 per value for the Jacobian itself (measured: a tenth of
    the time on 16 DOFs, 512 lines and three inputs, the same matrix to 2e-16).
    """
    n, n_in = M.shape[0], loads.shape[2]
    i, j = np.triu_indices(n)
    off = i != j
    A = np.zeros((5, n * n, n * n), dtype=complex)  # sum_l w^(4+k) T_l, k = 0..4, as [(i,k), (j,l)]
    V = np.zeros((3, n, n), dtype=complex)  # sum_l conj(f_m) w^2 G^H (v r) X^H
    per_line = n_in * n * n * 4
    step = max(1, _BLOCK_ENTRIES // per_line)
    for s in range(0, frf.omega.size, step):
        sl = slice(s, s + step)
        omega = frf.omega[sl]
        G, X = _receptance(M, C, K, omega, loads[sl])
        v = weight[sl]  # (l, n, n_in)
        # Q[l, b, i, k] = sum_a conj(G[a, i]) v[a, b]^2 G[a, k]
        Q = np.einsum("lai,lab,lak->lbik", G.conj(), v**2, G, optimize=True).reshape(-1, n * n)
        Z = (X.conj().transpose(0, 2, 1)[:, :, :, None] * X.transpose(0, 2, 1)[:, :, None, :]).reshape(-1, n * n)
        w_lb = np.repeat(omega, n_in)
        for k in range(5):
            A[k] += Q.T @ (w_lb[:, None] ** (4 + k) * Z)
        U = np.einsum("lai,lab->lib", G.conj(), v * r[sl])  # (l, n, n_in)
        UX = U @ X.conj().transpose(0, 2, 1)  # (l, n, n): [i, j] = sum_b U[i, b] conj(X[j, b])
        for m, f in enumerate((-(omega**2), 1j * omega, np.ones_like(omega))):
            V[m] += np.tensordot(np.conj(f) * omega**2, UX, axes=1)
    A = A.reshape(5, n, n, n, n).transpose(0, 1, 3, 2, 4)  # [k, i, j, k', l']

    def E(Ak: np.ndarray) -> np.ndarray:
        """The (P, P) block ``sum conj(D_p) D_q`` for the upper-triangle pairs p, q."""
        ii, jj, kk, ll = i[:, None], j[:, None], i[None, :], j[None, :]
        o_p, o_q = off[:, None], off[None, :]
        return (Ak[ii, jj, kk, ll] + o_q * Ak[ii, jj, ll, kk] + o_p * Ak[jj, ii, kk, ll]
                + (o_p & o_q) * Ak[jj, ii, ll, kk])

    # conj(f_m) f_m' w^4 = w^(4+k) times: M-M w^4 (k=4); M-C -i w^3 (3); M-K -w^2 (2);
    # C-C w^2 (2); C-K -i w (1); K-K 1 (0); the lower blocks are the conjugates.
    Ek = [E(A[k]) for k in range(5)]
    blocks = {(0, 0): Ek[4], (0, 1): -1j * Ek[3], (0, 2): -Ek[2], (1, 1): Ek[2], (1, 2): -1j * Ek[1],
              (2, 2): Ek[0]}
    P = i.size
    N = np.zeros((3 * P, 3 * P))
    for (a, b), B in blocks.items():
        blk = (B * scale[a] * scale[b]).real
        N[a * P:(a + 1) * P, b * P:(b + 1) * P] = blk
        N[b * P:(b + 1) * P, a * P:(a + 1) * P] = blk.T
    g = np.concatenate([((V[m][i, j] + off * V[m][j, i]) * scale[m]).real for m in range(3)])
    return N, g


def refine_mck_output_error(
    frf: FRFData,
    M: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    weight: np.ndarray,
    max_iter: int = 30,
    rtol: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Levenberg-Marquardt on the weighted output error of a symmetric M, C, K.

    Minimises ``sum w_kij^2 |H_kij - H^model_kij|^2`` over the upper triangles of M, C and K
    (3 n(n+1)/2 unknowns), the model's accelerance being ``-w^2 (K + i w C - w^2 M)^-1`` at
    the input DOFs: the maximum-likelihood symmetric model for Gaussian FRF noise of standard
    deviation ``1 / w``. Nothing keeps the iterates physical; the caller judges the result.

    Parameters
    ----------
    frf : FRFData
        Accelerances without reactions (n_freq, n_out, n_in); the inputs are among the outputs.
    M, C, K : (n_out, n_out)
        The start, over ``frf.outputs``.
    weight : (n_freq, n_out, n_in)
        ``1 / sigma`` per value, 0 where a value is left out.
    max_iter : int
        Most accepted steps.
    rtol : float
        Stop when an accepted step lowers the cost by less than this fraction.

    Returns
    -------
    (M, C, K, info) with ``info`` holding ``cost_start``, ``cost`` and ``iterations`` (the
    steps accepted).
    """
    n = M.shape[0]
    loads = loads_on_outputs(frf)[0]
    # One scale per matrix, so that the unknowns are O(1) and the Levenberg-Marquardt damping
    # (relative to the normal matrix's diagonal) treats M, C and K alike.
    scale = np.array([max(float(np.abs(A).max()), np.finfo(float).tiny) for A in (M, C, K)])
    iu = np.triu_indices(n)
    x = np.concatenate([M[iu] / scale[0], C[iu] / scale[1], K[iu] / scale[2]])
    mck = (M, C, K)
    r = _weighted_residual(frf, weight, loads, *mck)
    cost = cost0 = float(np.sum(np.abs(r) ** 2))
    mu, steps = 1e-6, 0
    for _ in range(max_iter):
        N, g = _normal_equations(frf, weight, loads, *mck, scale, r)
        accepted = False
        for _ in range(10):
            try:
                x_try = x - _solve_scaled(N, g, mu)
            except np.linalg.LinAlgError:
                mu *= 10
                continue
            mck_try = _unpack(x_try, n, scale)
            with np.errstate(all="ignore"):
                try:
                    r_try = _weighted_residual(frf, weight, loads, *mck_try)
                except np.linalg.LinAlgError:  # a singular Z at a line: not a better model
                    mu *= 10
                    continue
            cost_try = float(np.sum(np.abs(r_try) ** 2))
            if np.isfinite(cost_try) and cost_try < cost:
                accepted = True
                break
            mu *= 10
        if not accepted:
            break
        gain = (cost - cost_try) / cost
        x, mck, r, cost = x_try, mck_try, r_try, cost_try
        steps += 1
        mu = max(mu / 10, 1e-12)
        if gain < rtol:
            break
    return (*mck, {"cost_start": cost0, "cost": cost, "iterations": steps})
