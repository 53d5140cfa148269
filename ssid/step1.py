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
(:func:`ssid.step1_refine.refine_output_error`) instead minimises the weighted *output* error
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
from .modal import companion_matrix
from .solvers import column_scale, solve_ls, solve_tls

__all__ = [
    "Step1Data",
    "Step1Estimate",
    "step1_data",
    "step1_regressors",
    "estimate_equation_error",
    "starts_above_low_lines",
    "predict_accelerance",
    "reaction_transfer",
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
    weight_r : (L, n_r, n_in) float
        ``1/sigma`` of each reaction value on the same scale (inf: taken as exact).
    col_ok : (L, n_in) bool
        Column (k, j) usable by the equation-error form: no blanked value in ``H[k, :, j]``.
    in_idx, r_idx : DOF index of each input / reaction among the outputs.
    """

    omega: np.ndarray
    H: np.ndarray
    Hr: np.ndarray
    weight: np.ndarray
    weight_r: np.ndarray
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


def step1_data(
    frf: FRFData, weight: np.ndarray | None = None, weight_r: np.ndarray | None = None
) -> Step1Data:
    """Arrange an :class:`FRFData` for step 1; ``weight``/``weight_r`` are ``1/sigma``."""
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
        weight_r=np.full(Hr.shape, np.inf) if weight_r is None else np.asarray(weight_r, float),
        col_ok=valid.all(axis=1),
        in_idx=frf.input_index(),
        r_idx=frf.reaction_index(),
    )


def step1_regressors(d: Step1Data, Hx: np.ndarray, sl: slice = slice(None)) -> np.ndarray:
    """The regressor ``z_kj`` of Eq. 3.7 for the columns (k, j) of lines ``sl``.

    Each output's row of Eq. 3.7 reads ``h_kj^T + z_kj x = 0`` over the columns (line k,
    input j), with ``x`` the row of ``[C^ K^ D^_f D^_r]`` and ``z_kj`` the blocks
    ``[h/(j w), -h/w^2, -e_j, -r]`` (``r`` the reaction transfers of that column).

    Parameters
    ----------
    d : Step1Data
    Hx : (l, n_out, n_in) complex
        Accelerances of those lines (measured, or the model's).
    sl : slice of the record's lines (``l`` of them).

    Returns
    -------
    (l, n_in, p) complex, ``p = 2 n + n_in + n_r``.
    """
    L, n, n_in = Hx.shape
    w = d.omega[sl][:, None, None]
    h = np.swapaxes(Hx, 1, 2)  # (l, n_in, n)
    eye = np.broadcast_to(np.eye(n_in), (L, n_in, n_in))
    r = np.swapaxes(d.Hr[sl], 1, 2)  # (l, n_in, n_r)
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
    Z = step1_regressors(d, d.H)  # (L, n_in, p)
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


#: Lower edges of :func:`starts_above_low_lines`, as fractions of the highest line's frequency.
LOW_LINE_CUTS = (1 / 60, 1 / 15, 1 / 5)


def starts_above_low_lines(d: Step1Data, cuts: tuple[float, ...] = LOW_LINE_CUTS) -> dict[str, Step1Estimate]:
    """Scaled-TLS starts (Eq. 3.7) fitted to the lines above ``cut * f_max`` only.

    Why: under noise the equation error over all lines is ruled by the lowest ones, where the
    regressor ``-h/w^2`` is largest and a lightly damped mode narrower than the line spacing
    (the payload's suspension modes) changes ``h`` by decades from line to line. On the 10-DOF
    payload at 1-300 Hz under the report's noise, seeds 1-3, the LS, TLS and scaled-TLS starts
    over all lines were 2e9-7e10 in weighted output error and the refinement from the best of
    them ended 11-84 times above the minimum in the noise-free fit's basin
    (``bench/noisy_basins.py``), up to three targets above the band missed; these starts began
    117-385 times lower than the best of those and refined into that basin. The low modes are
    left to the refinement, which moves such well-separated roots easily. A start's own output
    error does not rank it against the all-line ones (it is always far lower):
    :func:`ssid.identify.identify_step1` refines both a little and compares then.

    Returns
    -------
    ``{"stls>5Hz": estimate, ...}``, one per cut that leaves out at least one line and keeps
    enough for the unknowns (``2 n_in`` real equations per line, ``p`` unknowns); a cut whose
    fit fails is left out.
    """
    f_hz = d.omega / (2 * np.pi)
    base = d.weight.mean(axis=1)
    out: dict[str, Step1Estimate] = {}
    for cut in cuts:
        f_cut = cut * f_hz[-1]
        keep = f_hz >= f_cut
        n_kept = int(np.count_nonzero(keep[:, None] & d.col_ok))
        if keep.all() or 2 * n_kept < d.p:
            continue
        try:
            out[f"stls>{f_cut:.3g}Hz"] = estimate_equation_error(d, "stls", line_weight=base * keep[:, None])
        except (np.linalg.LinAlgError, IdentificationError):
            continue
    return out


#: Entries (complex numbers) a block of lines may hold in the step-1 refinements' work
#: arrays; the blocks keep memory bounded whatever the number of lines.
_BLOCK_ENTRIES = 2_000_000


def _line_blocks(d: Step1Data) -> list[slice]:
    """Slices of lines whose weight and regressor work arrays stay below ``_BLOCK_ENTRIES``."""
    per_line = d.n_in * (d.n * d.n + d.p * d.p) + d.n * d.n
    step = max(1, _BLOCK_ENTRIES // per_line)
    L = d.omega.size
    return [slice(s, min(s + step, L)) for s in range(0, L, step)]


def _dynamic_matrix(d: Step1Data, est: Step1Estimate, sl: slice = slice(None)) -> np.ndarray:
    """``A_k = I + C^/(j w_k) - K^/w_k^2`` of the lines ``sl``, (l, n, n)."""
    w = d.omega[sl][:, None, None]
    return np.eye(d.n)[None] + est.C_hat[None] / (1j * w) - est.K_hat[None] / w**2


def _model_force(d: Step1Data, est: Step1Estimate, sl: slice = slice(None)) -> np.ndarray:
    """``D^_f + D^_r Hr_k`` of the lines ``sl``, (l, n, n_in)."""
    return est.Df_hat[None].astype(complex) + np.einsum("ir,krj->kij", est.Dr_hat, d.Hr[sl])


def predict_accelerance(d: Step1Data, est: Step1Estimate) -> np.ndarray:
    """Accelerance of the step-1 model, ``A_k^-1 (D^_f + D^_r Hr_k)``, (L, n, n_in).

    Through the model's complex modes when they are well conditioned: with the companion
    matrix ``[[0, I], [-K^, -C^]] = V diag(lambda) V^-1`` the accelerance is
    ``-w^2 V_x diag(1/(j w - lambda)) (V^-1)_v F``, O(n^2) per line instead of an O(n^3)
    solve. Near-defective modes (ill-conditioned V) take the direct solve.
    """
    n = d.n
    comp = companion_matrix(est.C_hat, est.K_hat)
    try:
        lam, V = np.linalg.eig(comp)
        modal = np.isfinite(lam).all() and np.linalg.cond(V) < 1e8
    except np.linalg.LinAlgError:
        modal = False
    Hm = np.empty(d.H.shape, dtype=complex)
    if modal:
        Vx = V[:n]
        Vv = np.linalg.inv(V)[:, n:]  # (2n, n)
        for sl in _line_blocks(d):
            w = d.omega[sl]
            G = Vv @ _model_force(d, est, sl)  # (l, 2n, n_in)
            q = G / (1j * w[:, None, None] - lam[None, :, None])
            Hm[sl] = -(w**2)[:, None, None] * (Vx @ q)
        return Hm
    for sl in _line_blocks(d):
        Hm[sl] = np.linalg.solve(_dynamic_matrix(d, est, sl), _model_force(d, est, sl))
    return Hm


def _weighted_gram(Ainv: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """``A^-H diag(w2[:, j]) A^-1`` for every line and input, (l, n_in, n, n).

    ``Ainv`` (l, n, n), ``w2`` (l, n_in, n). One batched product (an unoptimised
    three-operand einsum here was the refinements' largest cost).
    """
    AH = np.conj(np.swapaxes(Ainv, 1, 2))[:, None]  # (l, 1, n, n)
    return (AH * w2[:, :, None, :]) @ Ainv[:, None]


def reaction_transfer(d: Step1Data, est: Step1Estimate) -> np.ndarray:
    """``A_k^-1 D^_r``: accelerance per unit reaction force of the step-1 model, (L, n, n_r)."""
    G = np.empty((d.omega.size, d.n, d.n_r), dtype=complex)
    for sl in _line_blocks(d):
        A = _dynamic_matrix(d, est, sl)
        G[sl] = np.linalg.solve(A, np.broadcast_to(est.Dr_hat.astype(complex), (A.shape[0],) + est.Dr_hat.shape))
    return G


def _equation_weights(d: Step1Data, est: Step1Estimate, sl: slice) -> np.ndarray:
    """Inverse covariance of the equation error of the columns of lines ``sl``, (l, n_in, n, n).

    The equation error of column (k, j) is ``e = h + X z = A_k dh - D^_r dr``: the noise of the
    accelerances seen through ``A_k`` plus the noise of the measured reactions, which enter
    Eq. 3.6 as inputs (an errors-in-variables problem). Its covariance is
    ``S_kj = A_k diag(sigma_h^2) A_k^H + D^_r diag(sigma_r^2) D^_r^T`` and the weight is
    ``S_kj^-1``. Without reaction noise this is ``A^-H diag(w^2) A^-1``, and ``e^H S^-1 e`` is
    exactly the weighted output error. Columns holding a blanked value get weight 0 (their
    regressor is incomplete).
    """
    A = _dynamic_matrix(d, est, sl)
    w2 = np.swapaxes(d.weight[sl], 1, 2) ** 2  # (l, n_in, n)
    if d.n_r == 0 or np.all(np.isinf(d.weight_r)):
        W = _weighted_gram(np.linalg.inv(A), w2)
    else:
        var_h = np.where(w2 > 0, 1.0 / np.where(w2 > 0, w2, 1.0), 0.0)
        var_r = 1.0 / np.swapaxes(d.weight_r[sl], 1, 2) ** 2  # (l, n_in, n_r); 0 if exact
        S = np.einsum("kia,kja,kca->kjic", A, var_h, A.conj())
        S += np.einsum("ia,kja,ca->kjic", est.Dr_hat, var_r, est.Dr_hat)
        W = np.linalg.inv(S)
        W = (W + np.conj(np.swapaxes(W, -1, -2))) / 2
    return W * d.col_ok[sl][:, :, None, None]
