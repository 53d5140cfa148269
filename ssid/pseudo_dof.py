"""Pseudo degrees of freedom (report section 5.3, Eq. 5.24): more modes than sensors.

The record is split at its middle line; the low-frequency half is stacked on top of the
high-frequency half, so that each "pseudo line" k carries ``[H(w_k); H(w_k+N/2)]``: 2n pseudo
outputs for n sensors. Step 1 then has a model of order 2n, and Eq. 3.12 gives up to 2n modes.
Each element of the stacked regressor keeps its own frequency (``H/(j w)``, ``H/w^2`` with the
w of its half).

The report split the record in two. We allow ``p`` contiguous partitions of ``N // p`` lines
each (``n_partitions``; pseudo line k carries ``[H(w_k); H(w_k+L); ...]``, a model of order
``p n``): where the record holds more than 2n modes, two partitions cannot hold them all
(the payload of Table 6.18: 21 modes in 1-2100 Hz at 10 sensors, docs/replication.md
section 5). The top ``N mod p`` lines are left out.

Step 1 and the eigenproblem are what the report did. To tell structural from computational
modes (the report asks for an indicator) we use the *partition consistency* of a mode:
a structural mode lives in the partition whose lines hold its frequency (its "own"
partition; the nearest one for a root between or outside them). ``q = |phi_own|^2 / |phi|^2``
is near 1 for structural modes and spreads over the partitions for computational ones.
:func:`identify_pseudo_dof_auto` chooses p from the data and adds a second indicator: a
structural root is found again by the model with one partition more (a stabilisation test
across model orders); computational roots come and go.

Step 2 (the report left it open). What is physical in the pseudo model is a structural root
``lambda_r`` and the partition of its shape that carries its frequency, ``phi_r`` (n,): the
mode shape at the measured DOFs. The other partition, and the pseudo model's ``M^-1 C``,
``M^-1 K``, describe how the mode's tail looks in the other half of the record, which is not
a property of the structure. So step 2 is done on the measured FRFs, not on the pseudo DOFs:

1. :func:`pseudo_modal_model`: the scale factors ``1/a~_r`` of Eq. 3.23 for the roots and
   their measured-partition shapes, fitted to all measured lines with one factor per conjugate
   pair and residual terms for the modes not in the model (:func:`ssid.bands.fit_scale_factors`,
   as band processing does). Read as normal modes, each factor gives a modal mass
   ``m_r = -1 / (2 omega_dr Im u_r)``; a root whose fit asks for ``m_r <= 0`` cannot be a mode
   of a passive structure (a second, data-based indicator after the partition consistency).
2. :func:`pseudo_dof_mck`: M, C, K from the modes with ``m_r > 0``, as real normal modes with
   modal damping (:func:`ssid.bands.normal_mode_mck`). An n-DOF model holds n modes; with
   more, either the n strongest independent ones are kept (``n_keep = n``, the reduced
   physical model band processing builds), or all are kept in an m-DOF model whose first n
   coordinates are the measured DOFs and whose m - n others are generalised coordinates (the
   modal coordinates the sensors do not see, chosen orthogonal to the measured shapes). Both
   are positive definite when every kept modal mass is positive; the second reproduces the
   modal model at the measured DOFs exactly (up to the normal-mode reading of the factors).

The earlier attempt, the pseudo DOFs themselves as generalised coordinates
(``H(w) = sum_r u_r R_r(w) P_w theta_r (theta_r^T D_p)``, ``P_w`` the partition that carries
w, ``D_p = [D_f; D_f]``), is kept as :func:`pseudo_dof_fit_error` for comparison: it cannot
hold the measured FRFs (62 % relative RMS error on the payload of Table 6.18), because the
pseudo shapes of a mode in its other partition are not zero and not physical.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bands import (
    BandResult,
    BandRoot,
    fit_scale_factors,
    normal_mode_mck,
    strongest_roots,
)
from .errors import IdentificationError
from .frf import FRFData
from .modal import modal_phase_collinearity, root_frequency_damping
from .noise import frf_noise_weights
from .solvers import solve_ls
from .step1 import Step1Data, step1_data
from .step2 import state_space_modes

__all__ = [
    "PseudoDofMCK",
    "PartitionScan",
    "PseudoDofResult",
    "PseudoModalModel",
    "free_residue_error",
    "frf_relative_error",
    "identify_pseudo_dof",
    "identify_pseudo_dof_auto",
    "mck_accelerance",
    "modal_model_accelerance",
    "pseudo_dof_fit_error",
    "pseudo_dof_mck",
    "pseudo_modal_model",
]


@dataclass
class PseudoDofResult:
    """Modes of the pseudo-DOF model.

    Attributes
    ----------
    freq_hz, zeta, mpc, consistency : (m,) per oscillatory root, ascending frequency.
    structural : (m,) bool, the indicator's verdict (in band, positive damping,
        consistency >= threshold; from :func:`identify_pseudo_dof_auto` also repeated).
    lam : (m,) roots; theta : (2 p n, m) state eigenvectors of the pseudo model.
    u : (m,) complex modal scale factors from the step-2 attempt.
    split_hz : (p - 1,) the frequencies at which the record was split (between partitions).
    own : (m,) int, the partition carrying each root (0 = lowest frequencies).
    repeated : (m,) bool or None, whether the model with one partition more finds the root
        again (:func:`identify_pseudo_dof_auto`; None from :func:`identify_pseudo_dof`).
    scan : how the number of partitions was chosen, or None.
    """

    freq_hz: np.ndarray
    zeta: np.ndarray
    mpc: np.ndarray
    consistency: np.ndarray
    structural: np.ndarray
    lam: np.ndarray
    theta: np.ndarray
    u: np.ndarray
    split_hz: np.ndarray
    own: np.ndarray
    repeated: np.ndarray | None = None
    scan: PartitionScan | None = None

    @property
    def n_partitions(self) -> int:
        return self.split_hz.size + 1


@dataclass
class PartitionScan:
    """How :func:`identify_pseudo_dof_auto` chose the number of partitions.

    Attributes
    ----------
    n_partitions : (k,) the p tried (each compared with p + 1).
    n_consistent : (k,) roots passing the consistency indicator at each p.
    n_repeated : (k,) of those, the ones the model with p + 1 partitions repeats.
    chosen : the p used.
    settled : whether the chosen p met ``repeat_min`` (else it is the best fraction seen).
    repeat_min, repeat_rtol : the rule's thresholds.
    """

    n_partitions: np.ndarray
    n_consistent: np.ndarray
    n_repeated: np.ndarray
    chosen: int
    settled: bool
    repeat_min: float
    repeat_rtol: float


def _stack(frf: FRFData, n_partitions: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Pseudo lines: (L, p n, n_in) accelerances and (L, p n) frequencies (rad/s), L = N // p."""
    if frf.H_reaction is not None:
        raise IdentificationError("pseudo DOFs with measured reactions are not supported")
    ne = frf.n_freq // n_partitions
    w = frf.omega
    blocks = [slice(i * ne, (i + 1) * ne) for i in range(n_partitions)]
    H = np.concatenate([frf.H[b] for b in blocks], axis=1)
    W = np.concatenate([np.repeat(w[b, None], frf.n_out, 1) for b in blocks], axis=1)
    return H, W, ne


def _own_partition(f_hz: np.ndarray, freq_hz: np.ndarray, ne: int, n_partitions: int) -> np.ndarray:
    """Index of the partition whose lines hold each frequency (the nearest one otherwise)."""
    lo = np.array([freq_hz[i * ne] for i in range(n_partitions)])
    hi = np.array([freq_hz[(i + 1) * ne - 1] for i in range(n_partitions)])
    gap = np.maximum(lo[None, :] - f_hz[:, None], 0) + np.maximum(f_hz[:, None] - hi[None, :], 0)
    return np.argmin(gap, axis=1)


def identify_pseudo_dof(frf: FRFData, consistency_min: float = 0.8,
                        n_partitions: int = 2) -> PseudoDofResult:
    """Step 1 with pseudo DOFs (Eq. 5.24), Eq. 3.12, the indicator, and our step-2 attempt.

    Parameters
    ----------
    frf : FRFData without reactions and without blanked values, noise-free or not.
    consistency_min : threshold of the partition-consistency indicator.
    n_partitions : p, the number of partitions stacked (the report's Eq. 5.24: 2); the
        model has order p n for n sensors.
    """
    if not frf.valid_mask().all():
        raise IdentificationError("pseudo DOFs need a record without blanked values")
    if n_partitions < 2:
        raise ValueError("pseudo DOFs need at least 2 partitions")
    if 2 * (frf.n_freq // n_partitions) * frf.n_in < 2 * n_partitions * frf.n_out + frf.n_in:
        # fewer real equations per pseudo output than unknowns (Eq. 3.7 per column)
        raise IdentificationError(f"{frf.n_freq} lines cannot make {n_partitions} partitions "
                                  f"for {frf.n_out} outputs (too few lines per partition)")
    H, W, ne = _stack(frf, n_partitions)
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
    split = np.array([0.5 * (frf.freq_hz[i * ne - 1] + frf.freq_hz[i * ne])
                      for i in range(1, n_partitions)])
    n = frf.n_out
    th = modes.theta_x[:, :m].reshape(n_partitions, n, m)
    energy = np.sum(np.abs(th) ** 2, axis=1)  # (p, m)
    own = _own_partition(f, frf.freq_hz, ne, n_partitions)
    cols = np.arange(m)
    consistency = energy[own, cols] / energy.sum(axis=0)
    in_band = (f >= frf.freq_hz[0]) & (f <= frf.freq_hz[n_partitions * ne - 1])
    structural = in_band & (zeta > 0) & (consistency >= consistency_min)
    mpc = modal_phase_collinearity(th[own, :, cols].T)
    u = _pseudo_scale_factors(frf, modes, ne, n_partitions)
    return PseudoDofResult(freq_hz=f, zeta=zeta, mpc=mpc, consistency=consistency,
                           structural=structural, lam=modes.lam[:m], theta=modes.theta[:, :m],
                           u=u, split_hz=split, own=own)


def _repeated(freq_hz: np.ndarray, other_hz: np.ndarray, rtol: float) -> np.ndarray:
    """For each frequency, whether a root of ``other_hz`` within ``rtol`` of it repeats it.

    Matched one to one, closest pairs first (as criterion 4 of band processing), so that two
    roots of one model beside one mode are not both confirmed by its single estimate.
    """
    out = np.zeros(freq_hz.size, dtype=bool)
    if other_hz.size == 0 or freq_hz.size == 0:
        return out
    d = np.abs(other_hz[None, :] - freq_hz[:, None]) / freq_hz[:, None]
    used = np.zeros(other_hz.size, dtype=bool)
    for flat in np.argsort(d, axis=None):
        i, j = np.unravel_index(flat, d.shape)
        if d[i, j] >= rtol:
            break
        if not out[i] and not used[j]:
            out[i] = used[j] = True
    return out


def identify_pseudo_dof_auto(frf: FRFData, consistency_min: float = 0.8, max_partitions: int = 6,
                             repeat_min: float = 0.8, repeat_rtol: float = 0.01) -> PseudoDofResult:
    """Pseudo-DOF model with the number of partitions chosen from the data (stabilisation).

    A pseudo model of order p n holds at most p n modes, and the report's p = 2 is too few
    when the record holds more than about 2n modes (21 modes in 1-2100 Hz at 10 sensors in
    Table 6.18's case). A structural root of the model with p partitions is found again by
    the model with p + 1 (the stabilisation diagram's test across model orders, as criterion
    4 of band processing repeats a root across bands); a computational one comes and goes.
    p = 2, 3, ... is raised until at least ``repeat_min`` of the consistent roots repeat at
    p + 1 within ``repeat_rtol`` in frequency, and those repeated roots are the structural
    ones (``repeated``): consistency and repetition are both required.

    Parameters
    ----------
    frf : as for :func:`identify_pseudo_dof`.
    consistency_min : threshold of the partition-consistency indicator.
    max_partitions : largest p considered (p + 1 is computed to test it).
    repeat_min : fraction of consistent roots that must repeat at p + 1.
    repeat_rtol : relative frequency tolerance of a repeat.

    Returns
    -------
    PseudoDofResult with ``repeated`` and ``scan`` set. When no p meets ``repeat_min``
    (noisy data: the least-squares roots of Eq. 3.7 move with the order) the p with the
    largest repeated fraction is used and ``scan.settled`` is False.
    """
    results = {2: identify_pseudo_dof(frf, consistency_min, 2)}
    ps, n_cons, n_rep = [], [], []
    for p in range(2, max_partitions + 1):
        try:
            results[p + 1] = identify_pseudo_dof(frf, consistency_min, p + 1)
        except IdentificationError:  # too few lines per partition: p is the last one testable
            break
        a, b = results[p], results[p + 1]
        rep = _repeated(a.freq_hz[a.structural], b.freq_hz[b.structural], repeat_rtol)
        ps.append(p)
        n_cons.append(int(a.structural.sum()))
        n_rep.append(int(rep.sum()))
        if rep.size and rep.mean() >= repeat_min:
            break
    if not ps:
        raise IdentificationError("too few lines to compare pseudo models of 2 and 3 partitions")
    frac = np.array(n_rep) / np.maximum(n_cons, 1)
    settled = bool(frac[-1] >= repeat_min and n_cons[-1] > 0)
    chosen = ps[-1] if settled else ps[int(np.argmax(frac))]
    res = results[chosen]
    nxt = results[chosen + 1]
    repeated = np.zeros(res.freq_hz.size, dtype=bool)
    repeated[res.structural] = _repeated(res.freq_hz[res.structural], nxt.freq_hz[nxt.structural],
                                         repeat_rtol)
    res.structural = res.structural & repeated
    res.repeated = repeated
    res.scan = PartitionScan(np.array(ps), np.array(n_cons), np.array(n_rep), chosen, settled,
                             repeat_min, repeat_rtol)
    return res


def _pseudo_design(frf: FRFData, lam: np.ndarray, theta_x: np.ndarray, ne: int,
                   n_partitions: int) -> np.ndarray:
    """Columns of the step-2 model, (n_lines * n_out * n_in, n_modes), for all roots given."""
    n = frf.n_out
    w = frf.omega[: n_partitions * ne]
    R = -(w[:, None] ** 2) / (1j * w[:, None] - lam[None, :])  # (L, r)
    part = np.arange(n_partitions * ne) // ne
    Dp = np.vstack([np.eye(n)[:, frf.input_index()]] * n_partitions)  # (p n, n_in)
    q = theta_x.T @ Dp  # (r, n_in)
    rows = theta_x.reshape(n_partitions, n, -1)[part]  # (L, n, r)
    return np.einsum("kr,kir,rj->kijr", R, rows, q).reshape(-1, lam.size)


def _pseudo_scale_factors(frf: FRFData, modes, ne: int, n_partitions: int) -> np.ndarray:
    """Least-squares ``1/a~_r`` of the pseudo model's oscillatory pairs (conjugates tied)."""
    m = modes.n_pairs
    lam = modes.lam[: 2 * m]
    th = modes.theta_x[:, : 2 * m]
    E = _pseudo_design(frf, lam, th, ne, n_partitions)
    Et = np.hstack([E[:, :m] + E[:, m:], 1j * (E[:, :m] - E[:, m:])])
    y = frf.H[: n_partitions * ne].reshape(-1)
    v = solve_ls(np.vstack([Et.real, Et.imag]), np.concatenate([y.real, y.imag])[:, None])[:, 0]
    return v[:m] + 1j * v[m:]


def pseudo_dof_fit_error(frf: FRFData, res: PseudoDofResult, structural_only: bool = True) -> float:
    """Relative RMS error of the step-2 pseudo-DOF modal model against the measured FRFs."""
    p = res.n_partitions
    ne = frf.n_freq // p
    keep = res.structural if structural_only else np.ones(res.freq_hz.size, bool)
    lam = np.concatenate([res.lam[keep], res.lam[keep].conj()])
    th = res.theta[: res.theta.shape[0] // 2][:, keep]
    th = np.hstack([th, th.conj()])
    u = np.concatenate([res.u[keep], res.u[keep].conj()])
    Hm = (_pseudo_design(frf, lam, th, ne, p) @ u).reshape(p * ne, frf.n_out, frf.n_in)
    Hd = frf.H[: p * ne]
    return float(np.linalg.norm(Hm - Hd) / np.linalg.norm(Hd))


# --- Step 2 on the measured FRFs ------------------------------------------------------------


@dataclass
class PseudoModalModel:
    """Modal model of the measured DOFs from pseudo-DOF roots (step 2, Eq. 3.23).

    Attributes
    ----------
    roots : (m,) int, index of each mode in the :class:`PseudoDofResult` arrays.
    lam : (m,) complex roots, Im > 0, rad/s.
    phi : (n, m) complex shapes at the measured DOFs (the partition carrying the root).
    u : (m,) complex scale factors ``1/a~_r`` for that normalisation of ``phi``.
    modal_mass : (m,) ``m_r = -1 / (2 omega_dr Im(u_r e^{-2j alpha_r}))`` of the real shape
        ``Re(phi_r e^{j alpha_r})`` (kg for H in (m/s^2)/N and unit-free shapes); <= 0: the
        root is not a mode of a passive structure.
    in_idx : (n_in,) index of each input DOF among the outputs.
    weight : (L, n, n_in) ``1/sigma`` used in the fit (ones when the file gives no noise).
    """

    roots: np.ndarray
    lam: np.ndarray
    phi: np.ndarray
    u: np.ndarray
    modal_mass: np.ndarray
    in_idx: np.ndarray
    weight: np.ndarray

    @property
    def freq_hz(self) -> np.ndarray:
        return np.abs(self.lam) / (2 * np.pi)

    @property
    def physical(self) -> np.ndarray:
        return self.modal_mass > 0


@dataclass
class PseudoDofMCK:
    """M, C, K assembled from a pseudo-DOF modal model (:func:`pseudo_dof_mck`).

    Attributes
    ----------
    M, C, K : (N, N), N = n + n_generalised; coordinates ``0..n-1`` are the measured DOFs
        (outputs of the FRFData, in order), the rest generalised (modal) coordinates.
    modes : (N,) int, the modes of the :class:`PseudoModalModel` it holds.
    n_measured : n.
    """

    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    modes: np.ndarray
    n_measured: int

    @property
    def undamped_freq_hz(self) -> np.ndarray:
        ev = np.linalg.eigvals(np.linalg.solve(self.M, self.K)).real
        return np.sqrt(np.sort(np.maximum(ev, 0.0))) / (2 * np.pi)


def _real_phase(phi: np.ndarray) -> np.ndarray:
    """Phase ``alpha`` (m,) that makes each column of ``phi`` most nearly real.

    The same rule as :func:`ssid.bands.normal_mode_mck` (it maximises
    ``|Re(e^{j alpha} phi)|^2``), needed here to build generalised coordinates that leave it
    unchanged.
    """
    return -0.5 * np.angle(np.sum(phi * phi, axis=0))


def pseudo_modal_model(frf: FRFData, res: PseudoDofResult, roots: np.ndarray | None = None,
                       residuals: bool = True) -> PseudoModalModel:
    """Scale factors of pseudo-DOF roots fitted to the measured FRFs (Eq. 3.23, all lines).

    Parameters
    ----------
    frf : the FRFData the pseudo model came from (all lines, not stacked).
    res : from :func:`identify_pseudo_dof`.
    roots : indices into ``res`` of the roots to use (default: those flagged structural).
    residuals : residual terms (a constant and a ``w^2`` term per FRF) for the modes in the
        data but not among ``roots`` (:func:`ssid.bands.fit_scale_factors`).

    Returns
    -------
    PseudoModalModel
    """
    roots = np.flatnonzero(res.structural) if roots is None else np.asarray(roots, dtype=int)
    if roots.size == 0:
        raise IdentificationError("no pseudo-DOF roots to scale")
    n = frf.n_out
    # displacement partitions, lowest frequencies first: (p, n, m)
    th = res.theta[: res.n_partitions * n][:, roots].reshape(res.n_partitions, n, roots.size)
    # The shape at the measured DOFs is the partition that carries the root's frequency.
    phi = th[res.own[roots], :, np.arange(roots.size)].T
    lam = res.lam[roots]
    w = frf_noise_weights(frf)
    d = step1_data(frf, w)
    # All lines are one run: the residuals are one constant and one w^2 term per FRF.
    u = fit_scale_factors(d, lam, phi, np.zeros(frf.n_freq, dtype=int), residuals)
    alpha = _real_phase(phi)
    with np.errstate(divide="ignore"):
        mass = -1.0 / (2 * lam.imag * (u * np.exp(-2j * alpha)).imag)
    return PseudoModalModel(roots=roots, lam=lam, phi=phi, u=u, modal_mass=mass,
                            in_idx=frf.input_index(), weight=d.weight)


def modal_model_accelerance(model: PseudoModalModel, omega: np.ndarray,
                            modes: np.ndarray | None = None,
                            residual_fit: Step1Data | None = None) -> np.ndarray:
    """Accelerance (L, n, n_in) of the modal model (Eqs. 3.17, 3.19, 3.24), m/s^2 per N.

    ``H_kij = sum_r [u_r R_kr phi_ir phi_jr + conj(...)]``, ``R_kr = -w_k^2 / (j w_k - lambda_r)``.
    With ``residual_fit`` (the measured data on the same lines), the residual terms
    ``E0_ij + E2_ij w_k^2`` (real) are added, fitted by weighted least squares to what the
    modes leave of each FRF: with the scale factors of :func:`pseudo_modal_model` this is the
    joint optimum of that fit.
    """
    modes = np.arange(model.lam.size) if modes is None else np.asarray(modes, dtype=int)
    lam, phi, u = model.lam[modes], model.phi[:, modes], model.u[modes]
    w = np.asarray(omega, dtype=float)[:, None]
    R = -(w**2) / (1j * w - lam[None, :])
    Rc = -(w**2) / (1j * w - lam.conj()[None, :])
    q = phi[model.in_idx]  # (n_in, m)
    H = (np.einsum("kr,ir,jr->kij", R * u, phi, q)
         + np.einsum("kr,ir,jr->kij", Rc * u.conj(), phi.conj(), q.conj()))
    if residual_fit is not None:
        w2 = residual_fit.omega**2
        g = (w2 - w2.mean()) / max(np.ptp(w2), 1e-12 * w2.mean())
        G = np.column_stack([np.ones_like(g), g])
        G2 = np.vstack([G, np.zeros_like(G)])  # real unknowns: act on the real part only
        sw = residual_fit.weight
        rem = residual_fit.H - H
        for i in range(H.shape[1]):
            for j in range(H.shape[2]):
                s = np.concatenate([sw[:, i, j], sw[:, i, j]])
                y = np.concatenate([rem[:, i, j].real, rem[:, i, j].imag])
                c = np.linalg.lstsq(G2 * s[:, None], y * s, rcond=None)[0]
                H[:, i, j] += G @ c
    return H


def frf_relative_error(H_model: np.ndarray, H_data: np.ndarray) -> float:
    """Relative RMS error ``||H_model - H_data||_F / ||H_data||_F`` over all values."""
    return float(np.linalg.norm(H_model - H_data) / np.linalg.norm(H_data))


def mck_accelerance(M: np.ndarray, C: np.ndarray, K: np.ndarray, omega: np.ndarray,
                    n_measured: int, in_idx: np.ndarray) -> np.ndarray:
    """Accelerance (L, n_measured, n_in) of M, C, K at its first ``n_measured`` coordinates.

    Forces act at the measured DOFs ``in_idx`` only (Eq. 3.6 solved for the response:
    ``H = -w^2 (K + j w C - w^2 M)^-1 D_f``).
    """
    N = M.shape[0]
    D = np.eye(N)[:, in_idx]
    out = np.empty((len(omega), n_measured, len(in_idx)), dtype=complex)
    for k, w in enumerate(omega):
        out[k] = -(w**2) * np.linalg.solve(K + 1j * w * C - w**2 * M, D)[:n_measured]
    return out


def pseudo_dof_mck(frf: FRFData, model: PseudoModalModel, n_keep: int | None = None) -> PseudoDofMCK:
    """M, C, K (Eq. 3.26 read with real normal modes) from the physical modes of the model.

    Only modes with a positive modal mass are used. With ``n_keep`` (at most n, the number of
    measured DOFs), the ``n_keep`` strongest modes with shapes independent at the sensors are
    kept (:func:`ssid.bands.strongest_roots`: contribution to the FRFs at resonance, Eq. 3.17)
    and, for ``n_keep = n``, M, C, K are n x n in the measured DOFs (a reduced model: the
    other modes are lost). Without ``n_keep``, all m physical modes are kept in an m-DOF
    model ``x = T q`` of modal coordinates q: ``T = [Phi; Psi]`` with ``Phi`` (n, m) the real
    shapes at the measured DOFs and ``Psi`` (m - n, m) an orthonormal basis of the null space
    of ``Phi`` (generalised coordinates that the sensors do not see, so ``T`` is invertible
    when ``Phi`` has rank n). Then ``M = T^-T diag(m_r) T^-1``, ``K = T^-T diag(m_r w_r^2)
    T^-1``, ``C = T^-T diag(2 zeta_r w_r m_r) T^-1`` and the accelerance at the first n
    coordinates is the modal model's; ``Psi`` does not change it.

    Raises
    ------
    IdentificationError
        Fewer physical modes than coordinates asked for, or shapes of rank < n.
    """
    n = frf.n_out
    phys = np.flatnonzero(model.physical)
    if n_keep is not None:
        if n_keep > n:
            raise ValueError("n_keep cannot exceed the number of measured DOFs")
        roots = [BandRoot(0, complex(model.lam[r]),
                          np.concatenate([model.phi[:, r], model.lam[r] * model.phi[:, r]]),
                          float(model.freq_hz[r]),
                          float(-model.lam[r].real / abs(model.lam[r])), 1.0, cluster=i)
                 for i, r in enumerate(phys)]
        band = BandResult([(float(frf.freq_hz[0]), float(frf.freq_hz[-1]))], roots, roots,
                          [step1_data(frf, model.weight)])
        kept = strongest_roots(frf, band, n_keep).selected
        modes = np.array(sorted(phys[roots.index(r)] for r in kept), dtype=int)
        if modes.size < n_keep:
            raise IdentificationError(
                f"only {modes.size} physical modes with independent shapes (asked {n_keep})")
    else:
        modes = phys
    if modes.size < n:
        raise IdentificationError(
            f"{modes.size} physical modes cannot make an {n}-DOF model (Eq. 3.26 needs n)")
    lam, phi, u = model.lam[modes], model.phi[:, modes], model.u[modes]
    m = modes.size
    T = phi
    if m > n:
        alpha = _real_phase(phi)
        real = (phi * np.exp(1j * alpha)).real
        _, sv, Vt = np.linalg.svd(real)
        if sv[-1] < 1e-8 * sv[0]:
            raise IdentificationError("the kept shapes have rank < n at the sensors")
        psi = Vt[n:]  # (m - n, m): null space of the real shapes
        # Rotated by e^{-j alpha} so that normal_mode_mck's phase rule gives back alpha and the
        # real shapes become exactly [real; psi] (sum(psi^2) is real and positive).
        T = np.vstack([phi, psi * np.exp(-1j * alpha)[None, :]])
    M, C, K, _ = normal_mode_mck(lam, T, u)
    return PseudoDofMCK(M=M, C=C, K=K, modes=modes, n_measured=n)


def free_residue_error(frf: FRFData, lam: np.ndarray) -> float:
    """Relative RMS error of the best fit with these roots and free residues (a lower bound).

    Each FRF (i, j) gets its own complex residue per root (conjugate tied) and the real
    residual terms of :func:`ssid.bands.fit_scale_factors`; no shape, symmetry or
    positivity is imposed, so no model built on the roots ``lam`` (m,) (rad/s, Im > 0) can
    reproduce the FRFs better on these lines (unweighted). What is left is the modes that
    are not among the roots.
    """
    w = frf.omega[:, None]
    R = -(w**2) / (1j * w - lam[None, :])
    Rc = -(w**2) / (1j * w - np.conj(lam)[None, :])
    w2 = frf.omega**2
    g = (w2 - w2.mean()) / max(np.ptp(w2), 1e-12 * w2.mean())
    G = np.column_stack([np.ones_like(g), g])
    A = np.hstack([R + Rc, 1j * (R - Rc)])
    Ar = np.vstack([np.hstack([A.real, G]), np.hstack([A.imag, np.zeros_like(G)])])
    Y = frf.H.reshape(frf.n_freq, -1)
    Yr = np.vstack([Y.real, Y.imag])
    X = np.linalg.lstsq(Ar, Yr, rcond=None)[0]
    return float(np.linalg.norm(Ar @ X - Yr) / np.linalg.norm(Yr))
