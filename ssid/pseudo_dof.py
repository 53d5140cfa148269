"""Pseudo degrees of freedom (report section 5.3, Eq. 5.24): more modes than sensors.

The record is split at its middle line; the low-frequency half is stacked on top of the
high-frequency half, so that each "pseudo line" k carries ``[H(w_k); H(w_k+N/2)]``: 2n pseudo
outputs for n sensors. Step 1 then has a model of order 2n, and Eq. 3.12 gives up to 2n modes.
Each element of the stacked regressor keeps its own frequency (``H/(j w)``, ``H/w^2`` with the
w of its half).

Step 1 and the eigenproblem are what the report did. To tell structural from computational
modes (the report asks for an indicator) we use the *partition consistency* of a mode:
a structural mode below the split lives in the upper (low-frequency) partition of its shape,
one above the split in the lower partition. ``q = |phi_own|^2 / |phi|^2`` is near 1 for
structural modes and splits between both partitions for computational ones.

Step 2 is our attempt at the report's open question, treating the pseudo DOFs as generalised
coordinates: the accelerance at line w is modelled as
``H(w) = sum_r u_r R_r(w) P_w theta_r (theta_r^T D_p)`` with ``P_w`` the partition of the
pseudo coordinates that carries w and ``D_p = [D_f; D_f]`` (the same force acts in both
halves). It yields a modal model (poles, shapes, scale factors) that reproduces the FRFs,
not M, C, K in physical coordinates; :func:`pseudo_dof_fit_error` measures how well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .modal import modal_phase_collinearity, root_frequency_damping
from .solvers import solve_ls
from .step2 import state_space_modes

__all__ = ["PseudoDofResult", "identify_pseudo_dof", "pseudo_dof_fit_error"]


@dataclass
class PseudoDofResult:
    """Modes of the pseudo-DOF model.

    Attributes
    ----------
    freq_hz, zeta, mpc, consistency : (m,) per oscillatory root, ascending frequency.
    structural : (m,) bool, the indicator's verdict (in band, positive damping,
        consistency >= threshold).
    lam : (m,) roots; theta : (4n, m) state eigenvectors of the pseudo model.
    u : (m,) complex modal scale factors from the step-2 attempt.
    f_split_hz : the frequency at which the record was split.
    """

    freq_hz: np.ndarray
    zeta: np.ndarray
    mpc: np.ndarray
    consistency: np.ndarray
    structural: np.ndarray
    lam: np.ndarray
    theta: np.ndarray
    u: np.ndarray
    f_split_hz: float


def _stack(frf: FRFData) -> tuple[np.ndarray, np.ndarray, int]:
    """Pseudo lines: (Ne, 2n, n_in) accelerances and (Ne, 2n) frequencies (rad/s)."""
    if frf.H_reaction is not None:
        raise IdentificationError("pseudo DOFs with measured reactions are not supported")
    ne = frf.n_freq // 2
    w = frf.omega
    H = np.concatenate([frf.H[:ne], frf.H[ne : 2 * ne]], axis=1)
    W = np.concatenate([np.repeat(w[:ne, None], frf.n_out, 1),
                        np.repeat(w[ne : 2 * ne, None], frf.n_out, 1)], axis=1)
    return H, W, ne


def identify_pseudo_dof(frf: FRFData, consistency_min: float = 0.8) -> PseudoDofResult:
    """Step 1 with pseudo DOFs (Eq. 5.24), Eq. 3.12, the indicator, and our step-2 attempt.

    Parameters
    ----------
    frf : FRFData without reactions and without blanked values, noise-free or not.
    consistency_min : threshold of the partition-consistency indicator.
    """
    if not frf.valid_mask().all():
        raise IdentificationError("pseudo DOFs need a record without blanked values")
    H, W, ne = _stack(frf)
    n2, n_in = H.shape[1], frf.n_in
    h = np.swapaxes(H, 1, 2)  # (Ne, n_in, 2n)
    Wt = W[:, None, :]
    eye = np.broadcast_to(np.eye(n_in), (ne, n_in, n_in)).astype(complex)
    Z = np.concatenate([h / (1j * Wt), -h / Wt**2, -eye], axis=2).reshape(-1, 2 * n2 + n_in)
    Y = -h.reshape(-1, n2)
    X = solve_ls(np.vstack([Z.real, Z.imag]), np.vstack([Y.real, Y.imag])).T
    C_hat, K_hat = X[:, :n2], X[:, n2 : 2 * n2]
    modes = state_space_modes(C_hat, K_hat)
    m = modes.n_pairs
    wn, zeta = root_frequency_damping(modes.lam[:m])
    f = wn / (2 * np.pi)
    f_split = 0.5 * (frf.freq_hz[ne - 1] + frf.freq_hz[ne])
    th = modes.theta_x[:, :m]
    n = frf.n_out
    low = np.sum(np.abs(th[:n]) ** 2, axis=0)
    high = np.sum(np.abs(th[n:]) ** 2, axis=0)
    consistency = np.where(f < f_split, low, high) / (low + high)
    in_band = (f >= frf.freq_hz[0]) & (f <= frf.freq_hz[-1])
    structural = in_band & (zeta > 0) & (consistency >= consistency_min)
    mpc = modal_phase_collinearity(np.where(f < f_split, 1, 0)[None] * th[:n]
                                   + np.where(f < f_split, 0, 1)[None] * th[n:])
    u = _pseudo_scale_factors(frf, modes, ne)
    return PseudoDofResult(freq_hz=f, zeta=zeta, mpc=mpc, consistency=consistency,
                           structural=structural, lam=modes.lam[:m], theta=modes.theta[:, :m],
                           u=u, f_split_hz=float(f_split))


def _pseudo_design(frf: FRFData, lam: np.ndarray, theta_x: np.ndarray, ne: int) -> np.ndarray:
    """Columns of the step-2 model, (n_freq * n_out * n_in, n_modes), for all roots given."""
    n = frf.n_out
    w = frf.omega[: 2 * ne]
    R = -(w[:, None] ** 2) / (1j * w[:, None] - lam[None, :])  # (L, r)
    part = np.where(np.arange(2 * ne) < ne, 0, 1)
    Dp = np.vstack([np.eye(n)[:, frf.input_index()]] * 2)  # (2n, n_in)
    q = theta_x.T @ Dp  # (r, n_in)
    rows = np.stack([theta_x[:n], theta_x[n:]])[part]  # (L, n, r)
    return np.einsum("kr,kir,rj->kijr", R, rows, q).reshape(-1, lam.size)


def _pseudo_scale_factors(frf: FRFData, modes, ne: int) -> np.ndarray:
    """Least-squares ``1/a~_r`` of the pseudo model's oscillatory pairs (conjugates tied)."""
    m = modes.n_pairs
    lam = modes.lam[: 2 * m]
    th = modes.theta_x[:, : 2 * m]
    E = _pseudo_design(frf, lam, th, ne)
    Et = np.hstack([E[:, :m] + E[:, m:], 1j * (E[:, :m] - E[:, m:])])
    y = frf.H[: 2 * ne].reshape(-1)
    v = solve_ls(np.vstack([Et.real, Et.imag]), np.concatenate([y.real, y.imag])[:, None])[:, 0]
    return v[:m] + 1j * v[m:]


def pseudo_dof_fit_error(frf: FRFData, res: PseudoDofResult, structural_only: bool = True) -> float:
    """Relative RMS error of the step-2 pseudo-DOF modal model against the measured FRFs."""
    ne = frf.n_freq // 2
    keep = res.structural if structural_only else np.ones(res.freq_hz.size, bool)
    lam = np.concatenate([res.lam[keep], res.lam[keep].conj()])
    th = res.theta[: res.theta.shape[0] // 2][:, keep]
    th = np.hstack([th, th.conj()])
    u = np.concatenate([res.u[keep], res.u[keep].conj()])
    Hm = (_pseudo_design(frf, lam, th, ne) @ u).reshape(2 * ne, frf.n_out, frf.n_in)
    Hd = frf.H[: 2 * ne]
    return float(np.linalg.norm(Hm - Hd) / np.linalg.norm(Hd))
