"""The nominal model's receptance at the lines, in the pieces the candidate search needs.

Every candidate effect is a rank-one change ``delta u u^T`` of the dynamic stiffness
(``ssid.discrepancy.effects``), so by Sherman-Morrison its FRFs follow from the nominal
receptance ``G = Z^-1`` alone:

    H' = H - a P,   a = delta / (1 + delta u^T G u),   P = -omega^2 (S G u)(u^T G D)

``S G u`` needs the output rows of ``G``, ``u^T G D`` the input columns, and ``u^T G u`` a few
entries (the diagonal for one DOF, four entries for a pair). They are computed once, one
batched inversion of ``Z`` per block of lines, and never again per candidate.

On a test stand a substructure's "input" is not a unit force at one DOF: it also feels the
measured interface reactions (``ssid.frf.AppliedLoads``), so ``D`` becomes the per-line
load matrix ``D_l T_k`` (unit forces at the load DOFs times the forces per unit input);
the formula is unchanged.

Also here: the global modal damping ratio used when the model file has no C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from ..errors import InputError
from ..modal import MODAL_DAMPING_NEEDS_MASS
from ..tam import normal_modes

__all__ = [
    "NominalResponse",
    "fit_global_damping",
    "modal_accelerance",
    "nominal_response",
    "receptance_entries",
    "to_inputs",
    "unit_modal_damping",
]

#: Lines per batched inversion: bounds memory at chunk * n^2 complex values.
CHUNK_LINES = 128


@dataclass
class NominalResponse:
    """Pieces of the nominal receptance ``G(omega_k) = (K - omega_k^2 M + j omega_k C)^-1``.

    Attributes
    ----------
    omega : (n_freq,) rad/s
    G_out : (n_freq, n_out, n) complex
        Rows of ``G`` at the output DOFs (m/N).
    G_in : (n_freq, n, n_in) complex
        Columns of ``G`` at the input DOFs (under applied loads: ``G D_l T_k``).
    G_diag : (n_freq, n) complex
        Diagonal of ``G``.
    H : (n_freq, n_out, n_in) complex
        Nominal accelerance at the outputs and inputs, (m/s^2)/N.
    """

    omega: np.ndarray
    G_out: np.ndarray
    G_in: np.ndarray
    G_diag: np.ndarray
    H: np.ndarray


def _dynamic_stiffness(M, C, K, w: np.ndarray) -> np.ndarray:
    Z = K[None] - (w**2)[:, None, None] * M[None]
    if C is not None:
        Z = Z + 1j * w[:, None, None] * C[None]
    return Z


def _inverse(Z: np.ndarray, freq_hz: np.ndarray) -> np.ndarray:
    try:
        G = np.linalg.inv(Z)
    except np.linalg.LinAlgError:
        raise InputError(
            f"the model's dynamic stiffness K - w^2 M + j w C is singular between "
            f"{freq_hz[0]:g} and {freq_hz[-1]:g} Hz (an undamped resonance on a line?)"
        ) from None
    if not np.isfinite(G).all():
        raise InputError("the model's receptance is not finite at some line (singular K - w^2 M?)")
    return G


def to_inputs(X: np.ndarray, T: np.ndarray | None) -> np.ndarray:
    """Per-line columns at the load DOFs to columns per input: ``X[k] @ T[k]``.

    ``X``: (n_freq, ..., n_load); ``T``: (n_freq, n_load, n_in) or None (the load DOFs are
    the inputs, ``X`` is returned as it is).
    """
    return X if T is None else np.einsum("k...l,kli->k...i", X, T)


def nominal_response(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    omega: np.ndarray,
    out_idx: np.ndarray,
    in_idx: np.ndarray,
    T: np.ndarray | None = None,
) -> NominalResponse:
    """Receptance pieces of a model at the lines ``omega`` (see :class:`NominalResponse`).

    Parameters
    ----------
    M, C, K : (n, n)
        ``C`` None means undamped.
    omega : (n_freq,) rad/s
    out_idx, in_idx : int arrays
        Model indices of the output and input DOFs (with ``T``: of the load DOFs).
    T : (n_freq, n_load, n_in) complex, optional
        Forces at the load DOFs per unit input force (``ssid.frf.AppliedLoads.T``); None:
        a unit force at each input's DOF.
    """
    w = np.asarray(omega, dtype=float)
    n = M.shape[0]
    L = w.size
    G_out = np.empty((L, out_idx.size, n), dtype=complex)
    G_in = np.empty((L, n, in_idx.size if T is None else T.shape[2]), dtype=complex)
    G_diag = np.empty((L, n), dtype=complex)
    for s in range(0, L, CHUNK_LINES):
        sl = slice(s, min(L, s + CHUNK_LINES))
        G = _inverse(_dynamic_stiffness(M, C, K, w[sl]), w[sl] / (2 * np.pi))
        G_out[sl] = G[:, out_idx, :]
        G_in[sl] = to_inputs(G[:, :, in_idx], None if T is None else T[sl])
        G_diag[sl] = np.diagonal(G, axis1=1, axis2=2)
    H = -(w**2)[:, None, None] * to_inputs(G_out[:, :, in_idx], T)
    return NominalResponse(w, G_out, G_in, G_diag, H)


def receptance_entries(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    omega: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
) -> np.ndarray:
    """``G[rows[j], cols[j]]`` at every line, (n_freq, len(rows)) complex."""
    w = np.asarray(omega, dtype=float)
    out = np.empty((w.size, len(rows)), dtype=complex)
    for s in range(0, w.size, CHUNK_LINES):
        sl = slice(s, min(w.size, s + CHUNK_LINES))
        G = _inverse(_dynamic_stiffness(M, C, K, w[sl]), w[sl] / (2 * np.pi))
        out[sl] = G[:, rows, cols]
    return out


def unit_modal_damping(M: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``C_1`` with ``zeta C_1`` giving every mode the damping ratio ``zeta``, (n, n).

    ``C_1 = M Phi diag(2 omega_r) Phi^T M`` (mass-normalised real modes): modal damping is
    linear in the ratio, so one matrix serves every ``zeta``.
    """
    try:
        lam, phi = normal_modes(M, K)
    except np.linalg.LinAlgError:
        raise InputError(MODAL_DAMPING_NEEDS_MASS) from None
    Mphi = M @ phi
    C1 = Mphi @ np.diag(2 * np.sqrt(np.abs(lam))) @ Mphi.T
    return (C1 + C1.T) / 2


def modal_accelerance(
    lam: np.ndarray,
    phi: np.ndarray,
    out_idx: np.ndarray,
    in_idx: np.ndarray,
    omega: np.ndarray,
    zeta: float,
    u: np.ndarray | None = None,
    delta: np.ndarray | None = None,
    T: np.ndarray | None = None,
) -> np.ndarray:
    """Accelerance with modal damping ``zeta``, optionally with a rank-one effect, (n_freq, n_out, n_in).

    ``G = sum_r phi_r phi_r^T / (lam_r - w^2 + 2 j zeta sqrt(lam_r) w)`` (exact for modal
    damping, and far cheaper than a solve per line while ``zeta`` is searched); with ``u``
    (n,) and ``delta`` (n_freq,) the effect ``delta u u^T`` is added by Sherman-Morrison.
    ``in_idx`` and ``T`` as in :func:`nominal_response`.
    """
    w = np.asarray(omega, dtype=float)[:, None]
    inv_den = 1.0 / (lam[None, :] - w**2 + 2j * zeta * np.sqrt(np.abs(lam))[None, :] * w)
    po, pi = phi[out_idx], phi[in_idx]
    X = to_inputs(np.einsum("or,kr,ir->koi", po, inv_den, pi, optimize=True), T)
    if u is not None:
        pu = phi.T @ u  # (n_modes,): modal participation of the effect's direction
        g_o = (po * pu[None, :]) @ inv_den.T  # (n_out, n_freq)
        g_i = to_inputs(((pi * pu[None, :]) @ inv_den.T).T, T)  # (n_freq, n_in)
        g_uu = inv_den @ pu**2
        a = delta / (1 + delta * g_uu)
        X = X - a[:, None, None] * g_o.T[:, :, None] * g_i[:, None, :]
    return -(w[:, :, None] ** 2) * X


def fit_global_damping(
    H_meas: np.ndarray,
    W: np.ndarray,
    model_frf,
    zeta_range: tuple[float, float] = (1e-4, 0.3),
) -> float:
    """Modal damping ratio, the same for every mode, that best fits the measured FRFs.

    Weighted least squares over ``log zeta``: a coarse grid, then Brent in the best cell.

    Parameters
    ----------
    H_meas, W : (n_freq, n_out, n_in)
        Measured accelerance and its weights (0 where not valid).
    model_frf : callable
        ``model_frf(zeta) -> (n_freq, n_out, n_in)`` model accelerance (e.g.
        :func:`modal_accelerance` with or without an effect).
    """
    Hm = np.where(W > 0, H_meas, 0)

    def cost(log_zeta: float) -> float:
        with np.errstate(all="ignore"):
            val = float(np.sum(W**2 * np.abs(Hm - model_frf(float(np.exp(log_zeta)))) ** 2))
        return val if np.isfinite(val) else 1e300

    grid = np.linspace(np.log(zeta_range[0]), np.log(zeta_range[1]), 25)
    values = [cost(g) for g in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    with np.errstate(invalid="ignore", over="ignore"):
        res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    best = res.x if res.fun <= values[i] else grid[i]
    return float(np.exp(best))
