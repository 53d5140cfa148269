"""M, C, K of real normal modes (ssid.real_modes), against a known free-free chain."""

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.errors import IdentificationError
from ssid.real_modes import real_mode_mck


def _free_chain() -> tuple[np.ndarray, np.ndarray]:
    """A free-free chain of 4 masses (1-2.5 kg) and 3 springs (1e4-3e4 N/m): one rigid-body mode."""
    M = np.diag([1.0, 2.0, 1.5, 2.5])
    k = [1e4, 3e4, 2e4]
    K = np.zeros((4, 4))
    for i, ki in enumerate(k):
        K[i:i + 2, i:i + 2] += ki * np.array([[1, -1], [-1, 1]])
    return M, K


def test_real_mode_mck_returns_a_free_structure_from_its_modes():
    """The chain's own modes, scaled to modal masses 0.5-2 and given 1-3 % damping, give back
    its M and K and the modal damping matrix: errors are rounding (5e-16; the shapes' cond is 2.3)."""
    M, K = _free_chain()
    w2, phi = sla.eigh(K, M)
    w2[0] = 0.0  # the rigid-body mode, 1e-12 of the others by rounding
    scale = np.array([0.7, 1.3, 0.9, 1.1])  # shapes not mass-normalised
    phi = phi * scale
    m = scale**2  # phi^T M phi
    zeta = np.array([0.0, 0.01, 0.02, 0.03])
    wn = np.sqrt(w2)
    Mi, Ci, Ki = real_mode_mck(phi, 1 / m, wn, zeta)
    assert np.linalg.norm(Mi - M) / np.linalg.norm(M) < 1e-12
    assert np.linalg.norm(Ki - K) / np.linalg.norm(K) < 1e-12
    C = M @ phi @ np.diag(2 * zeta * wn / m) @ phi.T @ M  # modal damping, report section 6.2.3
    assert np.linalg.norm(Ci - C) / np.linalg.norm(C) < 1e-12
    assert np.abs(Ki @ np.ones(4)).max() < 1e-9 * np.abs(K).max()  # the rigid-body mode is free


def test_real_mode_mck_refuses_an_infinite_modal_mass():
    M, K = _free_chain()
    phi = sla.eigh(K, M)[1]
    with pytest.raises(IdentificationError, match="modal mass"):
        real_mode_mck(phi, np.array([1.0, 0.0, 1.0, 1.0]), np.ones(4), np.zeros(4))
