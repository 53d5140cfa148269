"""Step 2 for pseudo-DOF models (report section 5.3, which left it open): M, C, K.

What is physical in the pseudo model is a structural root ``lambda_r`` and the partition of
its shape that carries its frequency, ``phi_r`` (n,): the mode shape at the measured DOFs.
The other partitions, and the pseudo model's ``M^-1 C``, ``M^-1 K``, describe how the mode's
tail looks in the other parts of the record, which is not a property of the structure. So
step 2 is done on the measured FRFs, not on the pseudo DOFs:

1. :func:`pseudo_modal_model`: the scale factors ``1/a~_r`` of Eq. 3.23 for the roots and
   their measured-partition shapes, fitted to all measured lines with one factor per conjugate
   pair and residual terms for the modes not in the model (:func:`ssid.bands.fit_scale_factors`,
   as band processing does). Read as normal modes, each factor gives a modal mass
   ``m_r = -1 / (2 omega_dr Im u_r)``; a root whose fit asks for ``m_r <= 0`` is no mode of a
   passive structure as fitted: left out of every model, though still structural (the
   modal mass judges the fit of its shape and scale, not its frequency;
   :func:`ssid.pseudo_dof.flag_non_passive`).
2. :func:`pseudo_dof_mck`: M, C, K from the modes with ``m_r > 0``, as real normal modes with
   modal damping (:func:`ssid.real_modes.normal_mode_mck`). An n-DOF model holds n modes; with
   more, either the n strongest independent ones are kept (``n_keep = n``, the reduced
   physical model band processing builds), or all are kept in an m-DOF model whose first n
   coordinates are the measured DOFs and whose m - n others are generalised coordinates (the
   modal coordinates the sensors do not see, chosen orthogonal to the measured shapes). Both
   are positive definite when every kept modal mass is positive; the second reproduces the
   modal model at the measured DOFs exactly (up to the normal-mode reading of the factors).

The roots come from :func:`ssid.pseudo_dof.identify_pseudo_dof` (or its ``_auto`` variant).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .bands import (
    BandResult,
    BandRoot,
    fit_scale_factors,
    strongest_roots,
)
from .errors import IdentificationError
from .frf import FRFData
from .noise import frf_noise_weights
from .real_modes import normal_mode_mck
from .step1 import Step1Data, step1_data

if TYPE_CHECKING:  # annotations only: ssid.pseudo_dof imports this module
    from .pseudo_dof import PseudoDofResult

__all__ = [
    "PseudoDofMCK",
    "PseudoModalModel",
    "free_residue_error",
    "frf_relative_error",
    "mck_accelerance",
    "modal_model_accelerance",
    "pseudo_dof_mck",
    "pseudo_modal_model",
]


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

    The same rule as :func:`ssid.real_modes.normal_mode_mck` (it maximises
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
            f"{modes.size} physical modes cannot make a model of {n} DOFs (Eq. 3.26 needs {n})")
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
