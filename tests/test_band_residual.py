"""The residual pair fitted above a band (``ssid.band_residual``), on synthetic residuals of
known modes."""

from __future__ import annotations

import numpy as np
import pytest

from ssid.band_residual import fit_residual_pair, normal_mode_accelerance
from ssid.errors import IdentificationError

OMEGA = 2 * np.pi * np.linspace(5.0, 350.0, 400)
INPUTS = np.array([0, 2])


def _one_mode(f_hz: float, zeta: float, phi: np.ndarray) -> np.ndarray:
    lam = 2 * np.pi * f_hz * np.array([-zeta + 1j * np.sqrt(1 - zeta**2)])
    return normal_mode_accelerance(OMEGA, lam, phi[:, None], np.ones(1), INPUTS)


def test_a_residual_that_is_one_mode_above_the_band_gives_that_mode_back():
    """The residual is exactly one mode at 420 Hz (1.2 times the edge), 2 % damped, unit
    modal mass; with its damping given, the pair is that mode: measured 1.9e-8 in frequency
    and 4.7e-8 in the shape (relative norm). The bound 1e-6 is the scalar search's
    tolerance (1e-7 in log frequency) with room."""
    phi = np.array([0.3, -0.7, 1.1, 0.4])
    R = _one_mode(420.0, 0.02, phi)
    lam, phi_fit = fit_residual_pair(OMEGA, R, np.ones(R.shape), INPUTS, zeta=0.02)
    assert abs(lam) / (2 * np.pi) == pytest.approx(420.0, rel=1e-6)
    assert -lam.real / abs(lam) == pytest.approx(0.02, rel=1e-12)
    assert np.linalg.norm(phi_fit - phi) / np.linalg.norm(phi) < 1e-6


def test_a_residual_with_no_resonance_skirt_or_of_the_wrong_sign_is_refused():
    """A residual the found modes explain (zero) has no pole to find; one of negative
    driving-point flexibility (a mode's residual with its sign turned) is no mode's."""
    zero = np.zeros((OMEGA.size, 4, 2), dtype=complex)
    with pytest.raises(IdentificationError, match="no resonance"):
        fit_residual_pair(OMEGA, zero, np.ones(zero.shape), INPUTS, zeta=0.02)
    R = -_one_mode(420.0, 0.02, np.array([0.3, -0.7, 1.1, 0.4]))
    with pytest.raises(IdentificationError, match="not a mode's"):
        fit_residual_pair(OMEGA, R, np.ones(R.shape), INPUTS, zeta=0.02)


def test_blanked_values_do_not_enter_the_fit():
    """Values blanked by the analyser (NaN, weight 0) are left out: the same mode comes back."""
    phi = np.array([0.3, -0.7, 1.1, 0.4])
    R = _one_mode(420.0, 0.02, phi)
    w = np.ones(R.shape)
    R[100:140, 1, 0] = np.nan
    w[100:140, 1, 0] = 0.0
    lam, phi_fit = fit_residual_pair(OMEGA, R, w, INPUTS, zeta=0.02)
    assert abs(lam) / (2 * np.pi) == pytest.approx(420.0, rel=1e-6)
    assert np.linalg.norm(phi_fit - phi) / np.linalg.norm(phi) < 1e-6
