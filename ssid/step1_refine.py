"""SSID step 1, refined: from an equation-error start (:func:`ssid.step1.estimate_equation_error`)
to the weighted output error or errors-in-variables cost (report Eqs. 3.6-3.9).

Three refinements of a :class:`~ssid.step1.Step1Estimate`, each returning the best iterate
and an ``info`` dict (``cost_start``, ``cost``, ``iterations``):

* :func:`refine_sanathanan_koerner` - iteratively reweighted equation error with the
  equation-error covariance as a matrix weight (noisy reactions included);
* :func:`refine_line_weighted` - the same with one scalar weight per column, for models too
  large for the (n p)^2 normal matrix;
* :func:`refine_output_error` - Levenberg-Marquardt on the weighted output error, the
  maximum-likelihood estimate for Gaussian FRF noise with exact reactions.

:func:`oscillatory_start` turns a refined model's real roots into oscillatory pairs, a start
from which the output error can be refined out of the basin they sit in;
:func:`refine_roots_above_band` searches along the weakly determined frequencies of the roots
above the band.

The costs they minimise are :func:`output_error_cost` and :func:`errors_in_variables_cost`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.linalg as sla

from .errors import IdentificationError
from .noise import variance_of_weight
from .step1 import (
    Step1Data,
    Step1Estimate,
    _dynamic_matrix,
    _equation_weights,
    _line_blocks,
    _weighted_gram,
    estimate_equation_error,
    predict_accelerance,
    step1_regressors,
)
from .step2 import StateSpaceModes, state_space_modes

__all__ = [
    "refine_sanathanan_koerner",
    "refine_line_weighted",
    "refine_output_error",
    "oscillatory_start",
    "root_moved",
    "refine_roots_above_band",
    "output_error_cost",
    "errors_in_variables_cost",
]


def _equation_cost(d: Step1Data, est: Step1Estimate) -> float:
    """``sum_kj e^H S_kj^-1 e`` with the weights of the estimate itself (ML-type cost)."""
    X = est.to_x()
    c = 0.0
    try:
        for sl in _line_blocks(d):
            Z = step1_regressors(d, d.H[sl], sl)
            e = np.swapaxes(d.H[sl], 1, 2) + np.einsum("ab,kjb->kja", X, Z)
            c += float(np.einsum("kja,kjac,kjc->", e.conj(), _equation_weights(d, est, sl), e).real)
    except np.linalg.LinAlgError:
        return np.inf
    return c if np.isfinite(c) else np.inf


def _output_cost(d: Step1Data, Hm: np.ndarray) -> float:
    c = float(np.sum((d.weight * np.abs(d.H - Hm)) ** 2))
    return c if np.isfinite(c) else np.inf


class _NormalEquations:
    """Normal matrix and right-hand side of ``min sum_kj (v + X z)^H W (v + X z)`` over real X.

    For residuals ``X z_kj`` seen through an (n x n) Hermitian weight ``W_kj``,
    ``J^T W J = Re sum_kj kron(W_kj, G_kj)`` with ``G_kj = conj(z_kj) z_kj^T`` (p x p). The sum
    of Kronecker products is one matrix product of the flattened factors per block of lines,
    so memory stays bounded instead of holding the Jacobian's
    (lines x outputs x inputs) x (n p) entries. ``vec`` is row-major in X (index ``a p + b``);
    the minimiser solves ``N vec(X) = -g``.

    Both factors are Hermitian, so only their upper triangles are summed:
    ``Re(W_ab G_cd) = Re W_ab Re G_cd - Im W_ab Im G_cd``, and swapping ``a, b`` (or ``c, d``)
    keeps the real parts and flips the sign of the imaginary ones. That is a quarter of the
    products (n = 16, p = 35: 136 x 630 entries instead of 256 x 1225); this sum was the
    largest cost of :func:`refine_output_error` after the solve.
    """

    def __init__(self, n: int, p: int) -> None:
        self.n, self.p = n, p
        self._iw = np.triu_indices(n)
        self._ig = np.triu_indices(p)
        self._R = np.zeros((self._iw[0].size, self._ig[0].size))  # sum Re W_ab Re G_cd, a<=b, c<=d
        self._I = np.zeros_like(self._R)  # sum Im W_ab Im G_cd
        self._g = np.zeros((n, p))

    def add(self, Z: np.ndarray, W: np.ndarray, V: np.ndarray) -> None:
        """Add columns with regressors ``Z`` (m, n_in, p), weights ``W`` (m, n_in, n, n) and
        ``V = W v`` (m, n_in, n)."""
        n, p = self.n, self.p
        self._g += np.einsum("kja,kjb->ab", V, Z.conj()).real
        z = Z.reshape(-1, p)
        G = z.conj()[:, self._ig[0]] * z[:, self._ig[1]]
        Wu = W.reshape(-1, n, n)[:, self._iw[0], self._iw[1]]
        self._R += Wu.real.T @ G.real
        self._I += Wu.imag.T @ G.imag

    def matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N, g)``: (n p, n p) and (n p,)."""
        n, p = self.n, self.p
        index, sign = _kron_unpack(n, p)
        N = self._R.ravel()[index] - sign * self._I.ravel()[index]
        return N, self._g.reshape(n * p)


@lru_cache(maxsize=8)
def _kron_unpack(n: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Where entry ``(a p + c, b p + d)`` of the normal matrix lies in the upper-triangle sums
    of :class:`_NormalEquations` (flat index into its ``(n(n+1)/2, p(p+1)/2)`` arrays), and
    the sign its imaginary-part product takes there (-1 when exactly one pair is swapped)."""
    def packed(m: int) -> tuple[np.ndarray, np.ndarray]:
        iu = np.triu_indices(m)  # the order the sums are kept in
        pos = np.empty((m, m), dtype=np.intp)
        pos[iu] = np.arange(iu[0].size)
        pos[iu[1], iu[0]] = pos[iu]
        return pos, np.where(np.arange(m)[:, None] <= np.arange(m), 1.0, -1.0)

    uw, sw = packed(n)  # (n, n): a, b
    ug, sg = packed(p)  # (p, p): c, d
    n_g = p * (p + 1) // 2
    index = uw[:, None, :, None] * n_g + ug[None, :, None, :]  # (a, c, b, d)
    sign = sw[:, None, :, None] * sg[None, :, None, :]
    return index.reshape(n * p, n * p), sign.reshape(n * p, n * p)


def _solve_scaled(N: np.ndarray, rhs: np.ndarray, mu: float = 0.0) -> np.ndarray:
    """Solve ``(N + mu diag(N)) x = rhs`` after symmetric diagonal scaling.

    ``N`` is a Gram matrix, so Cholesky (half the work of LU, which was the refinements'
    largest cost) serves; where rounding has left the scaled matrix indefinite it fails, and
    LU solves as before. numpy's Cholesky, not scipy's: the wheels bundle separate OpenBLAS
    builds, and with two BLAS threads scipy's factorisation competed with numpy's spinning
    threads (the replication bench's section 4: 89 s against 43 s).
    """
    s = np.sqrt(np.abs(np.diag(N)))
    s[s == 0] = 1.0
    Ns = N / s[:, None] / s[None, :]
    Ns[np.diag_indices_from(Ns)] += mu
    try:
        L = np.linalg.cholesky(Ns)
    except np.linalg.LinAlgError:
        return np.linalg.solve(Ns, rhs / s) / s
    y = sla.solve_triangular(L, rhs / s, lower=True, check_finite=False)
    return sla.solve_triangular(L, y, lower=True, trans="T", check_finite=False) / s


def refine_sanathanan_koerner(
    d: Step1Data, est0: Step1Estimate, max_iter: int = 8, rtol: float = 1e-6
) -> tuple[Step1Estimate, dict]:
    """Iteratively reweighted equation error (Sanathanan-Koerner with a matrix weight).

    Each iteration solves the *linear* problem ``min sum e^H S_prev^-1 e`` with
    ``e = h + X z`` (``z`` from the measured FRFs) and ``S_prev`` the equation-error
    covariance at the previous iterate (:func:`_equation_weights`). At a fixed point this is
    the errors-in-variables ML-type cost; without reactions it is the weighted output error.
    It is the robust way into the basin of that minimum from a poor start.

    Returns the iterate with the lowest cost, and ``info``.
    """
    n, n_in = d.n, d.n_in
    best = est = est0
    best_cost = cost0 = _equation_cost(d, est0)
    it = stalled = 0
    for it in range(1, max_iter + 1):
        ne = _NormalEquations(n, d.p)
        try:
            for sl in _line_blocks(d):
                W = _equation_weights(d, est, sl)
                h = np.swapaxes(d.H[sl], 1, 2)
                ne.add(step1_regressors(d, d.H[sl], sl), W, np.einsum("kjac,kjc->kja", W, h))
            N, g = ne.matrix()
            X = -_solve_scaled(N, g).reshape(n, d.p)
        except np.linalg.LinAlgError:
            break
        est = Step1Estimate.from_x(X, n, n_in)
        cost = _equation_cost(d, est)
        if cost < best_cost:
            gain = (best_cost - cost) / best_cost
            best, best_cost, stalled = est, cost, 0
            if gain < rtol:
                break
        else:
            stalled += 1
            if stalled >= 2:  # two iterations without progress: a fixed point elsewhere
                break
    return best, {"cost_start": cost0, "cost": best_cost, "iterations": it}


def refine_line_weighted(
    d: Step1Data, est0: Step1Estimate, max_iter: int = 6
) -> tuple[Step1Estimate, dict]:
    """Iteratively reweighted equation error with one scalar weight per column (k, j).

    The cheap relative of :func:`refine_sanathanan_koerner` for models too large for its
    (n p)^2 normal matrix: the equation error ``A_k dh`` has covariance ``A_k S_h A_k^H``;
    a scalar weight can only equalise its size, ``w_kj^2 = n / trace(A_k S_h,kj A_k^H)``,
    not its shape. Each iteration is one least-squares solve of the step-1 size.

    Returns the iterate with the lowest weighted output error, and ``info``.
    """
    best = est = est0
    best_cost = cost0 = output_error_cost(d, est0)
    var = variance_of_weight(d.weight)
    it = 0
    w2 = (d.omega**2)[:, None]
    for it in range(1, max_iter + 1):
        # trace(A diag(var_j) A^H) = sum_a var_aj sum_i |A_ia|^2, and with C^, K^ real
        # sum_i |A_ia|^2 = 1 - 2 K_aa/w^2 + sum_i K_ia^2/w^4 + sum_i C_ia^2/w^2: no (L, n, n) array.
        K, C = est.K_hat, est.C_hat
        col = 1 - 2 * np.diag(K)[None] / w2 + (K**2).sum(0)[None] / w2**2 + (C**2).sum(0)[None] / w2
        tr = np.einsum("ka,kaj->kj", col, var)
        lw = np.sqrt(d.n / np.where(tr > 0, tr, np.inf))
        try:
            est = estimate_equation_error(d, "ls", line_weight=lw)
        except (np.linalg.LinAlgError, IdentificationError):
            break
        cost = output_error_cost(d, est)
        if cost < best_cost:
            gain = (best_cost - cost) / best_cost
            best, best_cost = est, cost
            if gain < 1e-4:
                break
    return best, {"cost_start": cost0, "cost": best_cost, "iterations": it}


def refine_output_error(
    d: Step1Data,
    est0: Step1Estimate,
    max_iter: int = 30,
    rtol: float = 1e-9,
) -> tuple[Step1Estimate, dict]:
    """Levenberg-Marquardt minimisation of the weighted output error of the step-1 model.

    Minimises ``sum w^2 |h_kj - A_k^-1 (D^_f e_j + D^_r r_kj)|^2``: the maximum-likelihood
    estimate when the accelerances are noisy and the reactions (if any) exact. With noisy
    reactions :func:`refine_sanathanan_koerner` and its errors-in-variables weight are used.

    Parameters
    ----------
    d : Step1Data
        Data with weights ``1/sigma`` (0 for blanked values).
    est0 : Step1Estimate
        Starting point (e.g. from :func:`refine_sanathanan_koerner`).
    max_iter : int
        Maximum number of accepted Gauss-Newton steps.
    rtol : float
        Stop when an accepted step lowers the cost by less than this fraction.

    Returns
    -------
    (Step1Estimate, info) with ``info`` holding ``cost_start``, ``cost``, ``iterations``.
    """
    n, n_in = d.n, d.n_in
    X = est0.to_x()
    Hm = predict_accelerance(d, est0)
    cost = cost0 = _output_cost(d, Hm)
    # Start as pure Gauss-Newton: the normal matrix is well posed but spans ~1e11 after
    # diagonal scaling, and any fixed damping would stall the weakly determined directions.
    # This schedule wastes solves (the undamped step was accepted in 29 of 1256 tries on two
    # chapter-6 records); a gain-ratio one (Nielsen's) reached a lower cost on 136 of 174 fits
    # in 0.4-0.75 of the time. It is kept because band processing relies on where these fits
    # stop: with the gain-ratio schedule lightly damped noise roots repeated across bands and
    # were taken for modes on 3 of 26 payload records (10 sensors 1-551 Hz, seeds 3 and 6; 12
    # sensors 1-650 Hz, seed 3), against none before.
    mu = 0.0
    it = 0
    est = est0
    for it in range(1, max_iter + 1):
        ne = _NormalEquations(n, d.p)
        for sl in _line_blocks(d):
            Ainv = np.linalg.inv(_dynamic_matrix(d, est, sl))
            w2 = d.weight[sl] ** 2
            W = _weighted_gram(Ainv, np.swapaxes(w2, 1, 2))
            V = np.einsum("kia,kij->kja", Ainv.conj(), w2 * (d.H[sl] - Hm[sl]))
            ne.add(step1_regressors(d, Hm[sl], sl), W, V)
        N, g = ne.matrix()
        accepted = False
        for _ in range(12):
            try:
                step = -_solve_scaled(N, g, mu)
            except np.linalg.LinAlgError:
                mu = max(10 * mu, 1e-10)
                continue
            est_try = Step1Estimate.from_x(X + step.reshape(n, d.p), n, n_in)
            Hm_try = predict_accelerance(d, est_try)
            cost_try = _output_cost(d, Hm_try)
            if cost_try < cost:
                accepted = True
                break
            mu = max(10 * mu, 1e-10)
        if not accepted:
            break
        gain = (cost - cost_try) / cost
        est, X, Hm, cost = est_try, est_try.to_x(), Hm_try, cost_try
        mu = mu / 100 if mu > 1e-9 else 0.0
        if gain < rtol:
            break
    info = {"cost_start": cost0, "cost": cost, "iterations": it}
    return Step1Estimate.from_x(X, n, n_in), info


def output_error_cost(d: Step1Data, est: Step1Estimate) -> float:
    """Weighted output error ``sum w^2 |H - H_model|^2`` of a step-1 estimate."""
    return _output_cost(d, predict_accelerance(d, est))


def errors_in_variables_cost(d: Step1Data, est: Step1Estimate) -> float:
    """``sum_kj e^H S_kj^-1 e`` of a step-1 estimate: the cost whose fixed point
    :func:`refine_sanathanan_koerner` seeks, with noisy reactions among the regressors.

    When ``d``'s weights are the noise's ``1/sigma`` (circular Gaussian), its expected value at
    the true model is the number of complex equations (valid lines x outputs x inputs), so
    an estimate whose cost is many times that of the true model is not the data's minimum.
    The weights :func:`ssid.identify.identify_step1` estimates (one level per FRF from its
    roughness) are that only approximately under noise proportional to the FRF, as the
    report's is. Without reactions, and with no value blanked, it equals the weighted output
    error :func:`output_error_cost`.
    """
    return _equation_cost(d, est)


def oscillatory_start(est: Step1Estimate) -> Step1Estimate | None:
    """``est`` with its real roots, paired nearest 0 first, made complex pairs: a restart.

    A lightly damped mode the lines barely resolve (a suspension mode between the first two
    lines, whose response changes sign from one to the next) can leave the output-error
    refinement in a basin where it is a pair of real roots, one of them unstable (10-DOF
    payload, 1-551 Hz, report noise, seed 2: roots -10.9 and +10.4 rad/s for the 1.29 Hz
    mode). No small step turns a real pair into an oscillatory one, so the refinement cannot
    leave that basin by itself. Each pair ``(l1, l2)`` becomes ``w (-zeta +- j sqrt(1 - zeta^2))``
    with ``w = sqrt(|l1 l2|)`` (the stiffness, its sign made positive) and
    ``zeta = min(|l1 + l2| / (2 w), 0.5)``, on the pair's common shape; every other root and
    eigenvector is kept, so the companion form ``[[0, I], [-K^, -C^]]`` holds by construction.

    Returns
    -------
    The start, or None when ``est`` has fewer than two real roots or the new eigenvectors are
    singular.
    """
    n = est.C_hat.shape[0]
    try:
        modes = state_space_modes(est.C_hat, est.K_hat)
    except IdentificationError:  # roots not in conjugate pairs: no start to build
        return None
    # Eq. 3.12's modes, real roots last and nearest 0 first, their eigenvectors real.
    lam, V = modes.lam.copy(), modes.theta.copy()
    real = np.arange(2 * modes.n_pairs, lam.size)
    if real.size < 2:
        return None
    for i, j in zip(real[0:-1:2], real[1::2], strict=False):
        l1, l2 = lam[i].real, lam[j].real
        w = np.sqrt(abs(l1 * l2))
        if w == 0:
            return None
        zeta = min(abs(l1 + l2) / (2 * w), 0.5)
        root = w * (-zeta + 1j * np.sqrt(1 - zeta**2))
        a, b = V[:n, i].real, V[:n, j].real
        phi = a / np.linalg.norm(a) + np.sign(a @ b or 1.0) * b / np.linalg.norm(b)
        if not np.linalg.norm(phi):
            return None
        phi = phi / np.linalg.norm(phi)
        V[:, i] = np.concatenate([phi, root * phi])
        V[:, j] = V[:, i].conj()
        lam[i], lam[j] = root, np.conj(root)
    return _estimate_from_modes(est, lam, V)


def _estimate_from_modes(est: Step1Estimate, lam: np.ndarray, V: np.ndarray) -> Step1Estimate | None:
    """``est`` with ``C^``, ``K^`` rebuilt from state-space roots ``lam`` (2n,) and eigenvectors
    ``V`` (2n, 2n) (Eq. 3.12 read backwards: the companion matrix ``V diag(lam) V^-1``), its
    ``D^`` kept; None when ``V`` is singular or the result not finite."""
    n = est.C_hat.shape[0]
    try:
        comp = (V @ np.diag(lam) @ np.linalg.inv(V)).real
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(comp)):
        return None
    return Step1Estimate(-comp[n:, n:], -comp[n:, :n], est.Df_hat.copy(), est.Dr_hat.copy())


def root_moved(est: Step1Estimate, r: int, factor: float,
               modes: StateSpaceModes | None = None) -> Step1Estimate | None:
    """``est`` with its ``r``-th oscillatory root pair (as ordered by
    :func:`ssid.step2.state_space_modes`) moved to ``factor`` times its natural frequency at
    the same damping ratio and shape; every other root and eigenvector kept. None when the
    eigenvectors are singular or ``r`` is not an oscillatory pair. ``modes``: ``est``'s
    :func:`~ssid.step2.state_space_modes`, if the caller has them already."""
    n = est.C_hat.shape[0]
    if modes is None:
        try:
            modes = state_space_modes(est.C_hat, est.K_hat)
        except IdentificationError:
            return None
    if not 0 <= r < modes.n_pairs:
        return None
    lam, V = modes.lam.copy(), modes.theta.copy()
    root = lam[r] * factor  # |lambda| scales, -Re/|lambda| (Eq. 5.19) stays
    phi = V[:n, r]
    V[:, r] = np.concatenate([phi, root * phi])
    V[:, r + modes.n_pairs] = V[:, r].conj()
    lam[r], lam[r + modes.n_pairs] = root, np.conj(root)
    return _estimate_from_modes(est, lam, V)


def refine_roots_above_band(
    d: Step1Data,
    est: Step1Estimate,
    factors: tuple[float, ...] = (0.9, 1.1),
    trial_iter: int = 8,
    max_rounds: int = 2,
    span: float = 2.0,
) -> tuple[Step1Estimate, dict]:
    """Search the output error along the frequencies of the roots above the band.

    A reduced-order model fitted below ``f_max`` holds some modes above it, seen only through
    their tail in the band. Their frequencies are weakly determined: the output error has a
    long, shallow valley along them, and :func:`refine_output_error` creeps along it and stops
    (10-DOF payload, 1-300 Hz, the report's noise: the 559 Hz mode at 478-481 Hz, where moving
    that root by 10 % and refining again lowered the output error). Each round tries every
    root between ``f_max`` and ``span * f_max`` moved by each of ``factors``
    (:func:`root_moved`), refines each try ``trial_iter`` steps, and refines the try of lowest
    cost to convergence if it is lower than the current model's; rounds stop when no try is
    lower. Only lower output error is accepted, so the result is never a worse
    maximum-likelihood fit than ``est``.

    Roots farther up are left alone: there a root stands for the tails of the modes beyond
    the band more than for one mode (the report's targets lay at most 2.1 times above its
    spectra's edges), and each root tried costs ``len(factors) * trial_iter`` refinement steps:
    on the 16-sensor payload at 1-551 Hz, with every root above the band tried (12 steps a
    try, three rounds), the search took 3.5 times as long as the fit before it and held no
    more targets.

    Parameters
    ----------
    d : Step1Data
        Data and noise weights, as for :func:`refine_output_error`.
    est : Step1Estimate
        A converged output-error fit.
    factors : tuple of float
        Frequency factors tried for each root above the band.
    trial_iter : int
        Levenberg-Marquardt steps per try.
    max_rounds : int
        At most this many accepted moves.
    span : float
        Roots up to this multiple of the highest line's frequency are tried.

    Returns
    -------
    (Step1Estimate, info) with ``info`` holding ``cost_start``, ``cost``, ``moves`` (one
    ``(frequency_hz, factor)`` per accepted move) and ``tries``.
    """
    omega_max = float(np.max(d.omega))
    cost = cost0 = output_error_cost(d, est)
    moves: list[tuple[float, float]] = []
    tries = 0
    for _ in range(max_rounds):
        try:
            modes = state_space_modes(est.C_hat, est.K_hat)
        except IdentificationError:
            break
        wn = np.abs(modes.lam[: modes.n_pairs])
        best = None
        for r in np.flatnonzero((wn > omega_max) & (wn <= span * omega_max)):
            for factor in factors:
                start = root_moved(est, int(r), factor, modes)
                if start is None:
                    continue
                tries += 1
                trial, trial_info = refine_output_error(d, start, max_iter=trial_iter)
                if trial_info["cost"] < cost and (best is None or trial_info["cost"] < best[0]):
                    best = (trial_info["cost"], trial, float(wn[r]) / (2 * np.pi), factor)
        if best is None:
            break
        # From below the current cost, and the refinement accepts only lower steps.
        est, refined = refine_output_error(d, best[1])
        cost = refined["cost"]
        moves.append((best[2], best[3]))
    return est, {"cost_start": cost0, "cost": cost, "moves": moves, "tries": tries}
