"""SSID step 1: estimate M^-1 C, M^-1 K, M^-1 D_f, M^-1 D_r from accelerance FRFs (Eqs. 3.6-3.9).

For every frequency line k and input j, Eq. 3.6 divided by M reads

    h_kj + C^ h_kj / (j w_k) - K^ h_kj / w_k^2 - D^_f e_j - D^_r r_kj = 0,

with ``h_kj = H[k, :, j]`` (accelerance column), ``r_kj = H_reaction[k, :, j]`` and the hats the
unknowns of Eq. 3.8. Stacking the regressor ``z_kj = [h/(jw); -h/w^2; -e_j; -r_kj]`` for all
(k, j) and splitting real and imaginary parts (Eq. 3.7, 3.9) gives ``X Z = -H`` with the real
unknown ``X = [C^ K^ D^_f D^_r]``, of shape (n, p), p = 2n + n_in + n_react.

The report solves this "equation error" form by LS or TLS. Its error, ``A_k dH`` with
``A_k = I + C^/(jw) - K^/w^2``, is not the measurement error: off resonance ``A_k`` is large,
near resonance nearly singular, so noisy lines far from the modes dominate the fit. Our default
(``refine_output_error``) instead minimises the weighted *output* error
``sum w^2 |H - A_k^-1 (D^_f e_j + D^_r r_kj)|^2`` by Gauss-Newton / Levenberg-Marquardt: with
weights ``w = 1/sigma`` this is the maximum-likelihood estimate for Gaussian FRF noise. Its
normal matrix has the Kronecker structure ``sum_kj kron(W_kj, G_kj)`` that is assembled with one
matrix product instead of a Jacobian of size (lines*outputs*inputs) x (n*p).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .solvers import column_scale, solve_ls, solve_tls

__all__ = [
    "Step1Data",
    "Step1Estimate",
    "step1_data",
    "estimate_equation_error",
    "refine_output_error",
    "refine_sanathanan_koerner",
    "predict_accelerance",
]


@dataclass
class Step1Data:
    """FRF data arranged for step 1.

    Attributes
    ----------
    omega : (L,) rad/s
    H : (L, n, n_in) complex accelerance; blanked values set to 0 (their weight is 0).
    Hr : (L, n_r, n_in) complex reaction FRFs (N/N).
    weight : (L, n, n_in) float
        ``1/sigma`` of each H value up to a common factor; 0 where blanked.
    col_ok : (L, n_in) bool
        Column (k, j) usable by the equation-error form: no blanked value in ``H[k, :, j]``.
    in_idx, r_idx : DOF index of each input / reaction among the outputs.
    """

    omega: np.ndarray
    H: np.ndarray
    Hr: np.ndarray
    weight: np.ndarray
    col_ok: np.ndarray
    in_idx: np.ndarray
    r_idx: np.ndarray

    @property
    def n(self) -> int:
        return self.H.shape[1]

    @property
    def n_in(self) -> int:
        return self.H.shape[2]

    @property
    def n_r(self) -> int:
        return self.Hr.shape[1]

    @property
    def p(self) -> int:
        return 2 * self.n + self.n_in + self.n_r


@dataclass
class Step1Estimate:
    """The step-1 matrices, all (n, .) real: ``X = [C^ K^ D^_f D^_r]`` (Eq. 3.8)."""

    C_hat: np.ndarray
    K_hat: np.ndarray
    Df_hat: np.ndarray
    Dr_hat: np.ndarray

    @classmethod
    def from_x(cls, X: np.ndarray, n: int, n_in: int) -> "Step1Estimate":
        return cls(X[:, :n], X[:, n : 2 * n], X[:, 2 * n : 2 * n + n_in], X[:, 2 * n + n_in :])

    def to_x(self) -> np.ndarray:
        return np.hstack([self.C_hat, self.K_hat, self.Df_hat, self.Dr_hat])


def step1_data(frf: FRFData, weight: np.ndarray | None = None) -> Step1Data:
    """Arrange an :class:`FRFData` for step 1; ``weight`` (L, n_out, n_in) is ``1/sigma``."""
    valid = frf.valid_mask()
    H = np.where(valid, frf.H, 0.0).astype(complex)
    if frf.H_reaction is None:
        Hr = np.zeros((frf.n_freq, 0, frf.n_in), dtype=complex)
    else:
        Hr = np.asarray(frf.H_reaction, dtype=complex)
    w = np.ones(H.shape) if weight is None else np.asarray(weight, dtype=float)
    w = np.where(valid, w, 0.0)
    return Step1Data(
        omega=frf.omega,
        H=H,
        Hr=Hr,
        weight=w,
        col_ok=valid.all(axis=1),
        in_idx=frf.input_index(),
        r_idx=frf.reaction_index(),
    )


def _regressors(d: Step1Data, Hx: np.ndarray) -> np.ndarray:
    """Regressor ``z_kj`` of every column (k, j), (L, n_in, p) complex, from accelerances ``Hx``."""
    L, n, n_in = Hx.shape
    w = d.omega[:, None, None]
    h = np.swapaxes(Hx, 1, 2)  # (L, n_in, n)
    eye = np.broadcast_to(np.eye(n_in), (L, n_in, n_in))
    r = np.swapaxes(d.Hr, 1, 2)  # (L, n_in, n_r)
    return np.concatenate([h / (1j * w), -h / w**2, -eye.astype(complex), -r], axis=2)


def estimate_equation_error(
    d: Step1Data, solver: str = "ls", line_weight: np.ndarray | None = None
) -> Step1Estimate:
    """Solve Eq. 3.7 in its equation-error form by LS, TLS or scaled TLS.

    Parameters
    ----------
    d : Step1Data
    solver : {"ls", "tls", "stls"}
        ``ls``: least squares (Eq. 5.5). ``tls``: the report's total least squares on the raw
        stacked data (Eqs. 5.12-5.14). ``stls``: scaled TLS (section 5.1.3): each column (k, j)
        weighted by ``line_weight`` (or the mean of ``d.weight`` over outputs), the columns of
        the data matrix equalised by their norms so that the C^, K^ and H blocks carry noise of
        comparable size, and the D^_f block, which is exact (unit forces), kept exact (mixed
        LS-TLS).
    line_weight : (L, n_in), optional
        Weight of each column (k, j) of Eq. 3.7 (``ls`` and ``stls``).

    Returns
    -------
    Step1Estimate
    """
    Z = _regressors(d, d.H)  # (L, n_in, p)
    Y = -np.swapaxes(d.H, 1, 2)  # (L, n_in, n)
    ok = d.col_ok
    if line_weight is None:
        line_weight = d.weight.mean(axis=1) if solver == "stls" else np.ones(ok.shape)
    wz = line_weight[ok][:, None]
    Zc, Yc = Z[ok] * wz, Y[ok] * wz
    A = np.vstack([Zc.real, Zc.imag])
    B = np.vstack([Yc.real, Yc.imag])
    if A.shape[0] < A.shape[1]:
        raise IdentificationError(
            f"step 1 has {A.shape[1]} unknowns per DOF but only {A.shape[0]} real equations: "
            "more valid frequency lines are needed"
        )
    n, n_in = d.n, d.n_in
    if solver == "ls":
        XT = solve_ls(A, B)
    elif solver == "tls":
        XT = solve_tls(A, B)
    elif solver == "stls":
        # Exact D^_f columns first for the mixed LS-TLS; the rest equalised by norm.
        order = np.r_[2 * n : 2 * n + n_in, 0 : 2 * n, 2 * n + n_in : d.p]
        s = column_scale(np.hstack([A, B]))
        sa, sb = s[: d.p], s[d.p :]
        XT_perm = solve_tls((A / sa)[:, order], B / sb, n_exact=n_in)
        XT = np.empty_like(XT_perm)
        XT[order] = XT_perm
        XT = XT / sa[:, None] * sb[None, :]
    else:
        raise ValueError(f"unknown step-1 solver {solver!r}")
    return Step1Estimate.from_x(XT.T, n, n_in)


def predict_accelerance(
    d: Step1Data, est: Step1Estimate, with_inverse: bool = False
) -> tuple[np.ndarray, np.ndarray | None]:
    """Accelerance predicted by the step-1 matrices: ``A_k^-1 (D^_f + D^_r Hr_k)``.

    Returns ``(Hm, Ainv)`` with ``Hm`` (L, n, n_in) and, if asked, ``Ainv`` (L, n, n).
    """
    n = d.n
    w = d.omega[:, None, None]
    A = np.eye(n)[None] + est.C_hat[None] / (1j * w) - est.K_hat[None] / w**2
    F = est.Df_hat[None].astype(complex) + np.einsum("ir,krj->kij", est.Dr_hat, d.Hr)
    if with_inverse:
        Ainv = np.linalg.inv(A)
        return Ainv @ F, Ainv
    return np.linalg.solve(A, F), None


def _weighted_cost(d: Step1Data, Hm: np.ndarray) -> float:
    return float(np.sum((d.weight * np.abs(d.H - Hm)) ** 2))


def _normal_equations(
    d: Step1Data, Z: np.ndarray, Ainv: np.ndarray, R: np.ndarray, w2: np.ndarray, chunk: int = 512
) -> tuple[np.ndarray, np.ndarray]:
    """Normal matrix and right-hand side of ``min sum w^2 |R_kj + A_k^-1 X z_kj|^2`` over real X.

    The map ``X -> A_k^-1 X z_kj`` has the Kronecker form ``J = z_kj^T (x) A_k^-1``, so
    ``J^T W J = Re sum_kj kron(W_kj, G_kj)`` with ``W_kj = A_k^-H diag(w_kj^2) A_k^-1`` (n x n)
    and ``G_kj = conj(z_kj) z_kj^T`` (p x p). The sum over (k, j) of the Kronecker products is
    one matrix product of the flattened factors, chunked so that memory stays
    O(chunk (n^2 + p^2)) instead of the Jacobian's (lines x outputs x inputs) x (n p).

    Parameters
    ----------
    Z : (L, n_in, p) regressors; Ainv : (L, n, n); R : (L, n, n_in); w2 : (L, n, n_in).

    Returns
    -------
    (N, g): (n p, n p) and (n p,), with ``vec`` row-major in X (index ``a p + b``); the
    minimiser solves ``N vec(X) = -g``.
    """
    n, p = d.n, d.p
    U = np.einsum("kia,kij->kja", Ainv.conj(), w2 * R)  # (L, n_in, n)
    g = np.einsum("kja,kjb->ab", U, Z.conj()).real.reshape(n * p)
    Wkj = np.einsum("kia,kij,kic->kjac", Ainv.conj(), w2, Ainv).reshape(-1, n * n)
    Zf = Z.reshape(-1, p)
    T = np.zeros((n * n, p * p))
    for s in range(0, Zf.shape[0], chunk):
        z = Zf[s : s + chunk]
        G = (z.conj()[:, :, None] * z[:, None, :]).reshape(-1, p * p)
        Wc = Wkj[s : s + chunk]
        T += Wc.real.T @ G.real - Wc.imag.T @ G.imag
    N = T.reshape(n, n, p, p).transpose(0, 2, 1, 3).reshape(n * p, n * p)
    return N, g


def _solve_scaled(N: np.ndarray, rhs: np.ndarray, mu: float = 0.0) -> np.ndarray:
    """Solve ``(N + mu diag(N)) x = rhs`` after symmetric diagonal scaling."""
    s = np.sqrt(np.abs(np.diag(N)))
    s[s == 0] = 1.0
    Ns = N / s[:, None] / s[None, :]
    return np.linalg.solve(Ns + mu * np.eye(Ns.shape[0]), rhs / s) / s


def refine_sanathanan_koerner(
    d: Step1Data, est0: Step1Estimate, max_iter: int = 8
) -> tuple[Step1Estimate, dict]:
    """Iteratively reweighted equation error (Sanathanan-Koerner, matrix weight ``A_k^-1``).

    Each iteration solves the *linear* problem ``min sum w^2 |A_prev,k^-1 (h_kj + X z_kj)|^2``
    (``z_kj`` from the measured FRFs): at a fixed point ``A_prev = A`` and the weighted
    equation error equals the output error ``h - A^-1 F``. It is the robust way into the
    basin of the output-error minimum; :func:`refine_output_error` then finishes. Columns
    with a blanked value are left out (their regressor is incomplete).

    Returns the iterate with the lowest output-error cost, and ``info``.
    """
    n, n_in = d.n, d.n_in
    Z = _regressors(d, d.H)
    w2 = d.weight**2 * d.col_ok[:, None, :]
    best = est0
    best_cost = cost0 = _weighted_cost(d, predict_accelerance(d, est0)[0])
    est = est0
    it = 0
    for it in range(1, max_iter + 1):
        _, Ainv = predict_accelerance(d, est, with_inverse=True)
        R = Ainv @ d.H
        N, g = _normal_equations(d, Z, Ainv, R, w2)
        try:
            X = -_solve_scaled(N, g).reshape(n, d.p)
        except np.linalg.LinAlgError:
            break
        est = Step1Estimate.from_x(X, n, n_in)
        cost = _weighted_cost(d, predict_accelerance(d, est)[0])
        if not np.isfinite(cost):
            break
        if cost < best_cost:
            gain = (best_cost - cost) / best_cost
            best, best_cost = est, cost
            if gain < 1e-6:
                break
    return best, {"cost_start": cost0, "cost": best_cost, "iterations": it}


def refine_output_error(
    d: Step1Data,
    est0: Step1Estimate,
    max_iter: int = 30,
    rtol: float = 1e-9,
) -> tuple[Step1Estimate, dict]:
    """Levenberg-Marquardt minimisation of the weighted output error of the step-1 model.

    Parameters
    ----------
    d : Step1Data
        Data with weights ``1/sigma`` (0 for blanked values).
    est0 : Step1Estimate
        Starting point (e.g. from :func:`estimate_equation_error`).
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
    Hm, Ainv = predict_accelerance(d, est0, with_inverse=True)
    cost = cost0 = _weighted_cost(d, Hm)
    # Start as pure Gauss-Newton: the normal matrix is well posed but spans ~1e11 after
    # diagonal scaling, and any fixed damping would stall the weakly determined directions.
    mu = 0.0
    it = 0
    for it in range(1, max_iter + 1):
        N, g = _normal_equations(d, _regressors(d, Hm), Ainv, d.H - Hm, d.weight**2)
        accepted = False
        for _ in range(12):
            try:
                step = -_solve_scaled(N, g, mu)
            except np.linalg.LinAlgError:
                mu = max(10 * mu, 1e-10)
                continue
            X_try = X + step.reshape(n, d.p)
            est_try = Step1Estimate.from_x(X_try, n, n_in)
            Hm_try, Ainv_try = predict_accelerance(d, est_try, with_inverse=True)
            cost_try = _weighted_cost(d, Hm_try)
            if np.isfinite(cost_try) and cost_try < cost:
                accepted = True
                break
            mu = max(10 * mu, 1e-10)
        if not accepted:
            break
        gain = (cost - cost_try) / cost
        X, Hm, Ainv, cost = X_try, Hm_try, Ainv_try, cost_try
        mu = mu / 100 if mu > 1e-9 else 0.0
        if gain < rtol:
            break
    info = {"cost_start": cost0, "cost": cost, "iterations": it}
    return Step1Estimate.from_x(X, n, n_in), info
