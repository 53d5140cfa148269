"""Band processing's scale factors (BP2, BP3, Eq. 3.23) and M, C, K assembly (Eq. 3.26, real
normal modes) on a chain with known M, C, K: 10 DOFs, 5 measured, a 5-DOF reduced model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.bands import (
    overlapping_bands,
    process_bands,
    scale_selected_roots,
    strongest_roots,
)
from ssid.errors import IdentificationError
from ssid.frf import accelerance_from_model
from ssid.models.payload import modal_damping
from ssid.noise import report_noise_frf
from ssid.real_modes import normal_mode_mck

_SENS = [1, 3, 5, 7, 9]


@pytest.fixture(scope="module")
def chain():
    n = 10
    m = np.array([1.0, 1.2, 0.9, 1.1, 1.0, 0.8, 1.3, 1.0, 0.9, 1.1])  # kg
    k = 1e5 * np.array([1.0, 1.5, 0.8, 1.2, 1.1, 0.9, 1.4, 1.0, 1.3, 0.7])  # N/m
    K = np.zeros((n, n))
    K[0, 0] = k[0]  # spring 0 to ground, spring i between DOFs i-1 and i
    for i in range(1, n):
        K[i - 1, i - 1] += k[i]
        K[i, i] += k[i]
        K[i - 1, i] -= k[i]
        K[i, i - 1] -= k[i]
    M = np.diag(m)
    C = modal_damping(M, K, 0.02)
    lam, phi = sla.eigh(K, M)
    f = np.sqrt(lam) / (2 * np.pi)  # 7.7, 23.1, 36.3, 47.4, 60.7, 73.3, 91.3, 96.8, ... Hz
    dofs = [str(i) for i in range(n)]
    f_hi = 0.5 * (f[6] + f[7])  # 7 modes in the data
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(2, f_hi, 800),
                                 [dofs[i] for i in _SENS], ["3", "9"])
    ps = phi[_SENS][:, :5]
    M5 = np.linalg.inv(ps @ ps.T)
    K5 = np.linalg.inv(ps @ np.diag(1 / lam[:5]) @ ps.T)
    return frf, overlapping_bands(2, f_hi, 12.0, 0.5), f[:5], M5, K5


def _keep_lowest5(frf, res, f5):
    """The analyst's choice (as the report's): the roots nearest the 5 target modes."""
    prefer = [int(np.argmin(np.abs(res.freq_hz - f))) for f in f5]
    return strongest_roots(frf, res, 5, prefer=prefer)


def _errors(mck, f5, M5, K5):
    M, _, K = mck
    assert np.linalg.eigvalsh(M).min() > 0 and np.linalg.eigvalsh(K).min() > 0
    fu = np.sqrt(sla.eigh(K, M, eigvals_only=True)) / (2 * np.pi)
    return (np.max(np.abs(fu / f5 - 1)), np.linalg.norm(M - M5) / np.linalg.norm(M5),
            np.linalg.norm(K - K5) / np.linalg.norm(K5))


def test_normal_mode_assembly_is_exact_and_robust_to_complex_shapes():
    """Exact modes and scale factors of a known system give back its M, C, K (Eq. 3.26 with
    real normal modes). Shapes perturbed by a complex 1e-3 (relative, random: what noisy bands
    give) move the normal-mode M by about as much (tolerance 3e-3), while the full state-space
    inverse (step2.assemble_mck) over a 1-2000 Hz span amplifies it (measured 8x): its M is
    ``(M^-1 + X K X)^-1`` with the residue ``X = Theta_x diag(u) Theta_x^T`` multiplied by the
    stiffness of the highest modes."""
    from ssid.step2 import StateSpaceModes, assemble_mck

    rng = np.random.default_rng(0)
    n = 8
    Phi = np.linalg.qr(rng.standard_normal((n, n)))[0] @ np.diag(rng.uniform(0.5, 2, n))
    w = 2 * np.pi * np.geomspace(1.0, 2000.0, n)  # rad/s, three decades as on the payload
    Minv = Phi @ Phi.T  # mass-normalised shapes Phi: M^-1 = Phi Phi^T
    M = np.linalg.inv(Minv)
    K = np.linalg.inv(Phi @ np.diag(1 / w**2) @ Phi.T)
    C = modal_damping(M, K, 0.02)
    z = 0.02
    lam = -z * w + 1j * w * np.sqrt(1 - z * z)
    u = 1 / (2j * lam.imag)  # 1/a~_r of a mass-normalised real mode (Eq. 3.23)
    Mi, Ci, Ki, mr = normal_mode_mck(lam, Phi * np.exp(0.7j), u * np.exp(-1.4j))
    for A, B in ((Mi, M), (Ci, C), (Ki, K)):
        assert np.linalg.norm(A - B) / np.linalg.norm(B) < 1e-8
    assert np.allclose(mr, 1.0)
    rng = np.random.default_rng(0)
    th = Phi * (1 + 1e-3 * (rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))))
    e_normal = np.linalg.norm(normal_mode_mck(lam, th, u)[0] - M) / np.linalg.norm(M)
    theta = np.vstack([th, th * lam])
    Ms = assemble_mck(StateSpaceModes(np.concatenate([lam, lam.conj()]),
                                      np.hstack([theta, theta.conj()]), n),
                      np.concatenate([u, u.conj()]))[0]
    e_state_space = np.linalg.norm(Ms - M) / np.linalg.norm(M)
    assert e_normal < 3e-3
    assert e_state_space > 5 * e_normal


def test_dependent_shapes_are_not_kept_and_cannot_be_assembled(chain):
    """A root whose shape at the sensors is another's (a symmetric structure's extra symmetric
    mode) makes the mode matrix of Eq. 3.26 singular: strongest_roots skips it and
    scale_selected_roots refuses it instead of returning a meaningless M."""
    frf, bands, f5, _, _ = chain
    res = process_bands(frf, bands, solver="ls")
    kept = _keep_lowest5(frf, res, f5)
    r0 = kept.selected[0]
    twin = replace(r0, lam=r0.lam * 1.8, theta=np.concatenate([2 * r0.theta[:5],
                                                               2 * r0.lam * 1.8 * r0.theta[:5]]),
                   freq_hz=r0.freq_hz * 1.8)
    bad = replace(kept, selected=[twin] + kept.selected[:4])
    with pytest.raises(IdentificationError, match="linearly dependent"):
        scale_selected_roots(frf, bad, "BP2")
    fixed = strongest_roots(frf, replace(kept, selected=[twin] + kept.selected), 5,
                            prefer=[1, 2, 3, 4, 5])
    assert all(r is not twin for r in fixed.selected)


def test_bp2_bp3_recover_reduced_mck_noise_free(chain):
    """Noise-free. The band roots are good to 3e-4 in frequency (a 5-DOF band model of 10-DOF
    data is not exact), so the undamped frequencies of the assembled M, C, K must be within
    1e-3 and M, K within 1 % of the exact reduced model (measured: <= 6e-4 and <= 0.7 %).
    Without the residual terms BP3 is several times worse (1.9 % on M)."""
    frf, bands, f5, M5, K5 = chain
    res = process_bands(frf, bands, solver="ls")
    kept = _keep_lowest5(frf, res, f5)
    for method in ("BP2", "BP3"):
        for assembly in ("state-space", "normal"):
            ef, em, ek = _errors(scale_selected_roots(frf, kept, method, assembly=assembly)[1],
                                 f5, M5, K5)
            assert ef < 1e-3 and em < 0.01 and ek < 0.01, (method, assembly, ef, em, ek)
    em_res = _errors(scale_selected_roots(frf, kept, "BP3")[1], f5, M5, K5)[1]
    em_nores = _errors(scale_selected_roots(frf, kept, "BP3", residuals=False)[1], f5, M5, K5)[1]
    assert em_nores > 3 * em_res


def test_bp2_bp3_recover_reduced_mck_with_report_noise(chain):
    """The report's noise model (addnoise: 2 % of each FRF's RMS magnitude, 2 degrees, uniform,
    40 averages, on responses and forces), seed 3, default (ml) band solver. The roots come
    within 1e-4 of the true frequencies; the assembled M, C, K within 5e-4 (measured 2.5e-4)
    and M, K within 0.5 % of the exact reduced model (measured <= 0.2 %)."""
    frf, bands, f5, M5, K5 = chain
    noisy = report_noise_frf(frf, seed=3)
    res = process_bands(noisy, bands)
    kept = _keep_lowest5(noisy, res, f5)
    assert np.max(np.abs(kept.freq_hz / f5 - 1)) < 1e-4
    for method in ("BP2", "BP3"):
        for assembly in ("state-space", "normal"):
            ef, em, ek = _errors(scale_selected_roots(noisy, kept, method, assembly=assembly)[1],
                                 f5, M5, K5)
            assert ef < 5e-4 and em < 5e-3 and ek < 5e-3, (method, assembly, ef, em, ek)
