"""The residual pair fitted above a band and the rigid-body modes fitted to the mass line
below it (``ssid.band_residual``), on synthetic residuals of known modes."""

from __future__ import annotations

import numpy as np
import pytest

from ssid.band_residual import fit_residual_pair, fit_rigid_body_modes, normal_mode_accelerance
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


def _mass_line_and_flexibility(phi_rb: np.ndarray, flex: np.ndarray) -> np.ndarray:
    """``phi_rb phi_rb_in^T - w^2 F_in``: rigid-body modes (unit modal mass) plus the residual
    flexibility of modes far above (``flex`` (n, n) symmetric), at the inputs' columns."""
    A = phi_rb @ phi_rb[INPUTS].T
    return (A[None] - OMEGA[:, None, None] ** 2 * flex[:, INPUTS][None]).astype(complex)


def test_a_mass_line_gives_the_rigid_body_modes_back():
    """A translation and a rotation of 4 points on a line (unit modal mass) plus residual
    flexibility of modes far above: the two shapes come back up to a rotation among
    themselves (any basis of the rigid-body motions is one), so their mass line
    ``Phi Phi_in^T`` must be the given one. Measured 1.8e-15 (relative norm); the bound 1e-9
    is rounding with room. The flexibility, 2.5 times the mass line at the top line, does not
    leak into it: it is fitted alongside. Below 22 Hz the mass line is 99.994 % of the
    residual's power (the rest is the flexibility's w^2 term there)."""
    x = np.array([0.0, 0.4, 0.8, 1.2])
    phi_rb = np.column_stack([np.full(4, 0.5), (x - x.mean()) / np.linalg.norm(x - x.mean())])
    rng = np.random.default_rng(4)
    B = rng.standard_normal((4, 4))
    flex = 1e-7 * (B @ B.T)  # (m/N) modes above the band: 2.5 times the mass line at the top line
    R = _mass_line_and_flexibility(phi_rb, flex)
    phi, share = fit_rigid_body_modes(OMEGA, R, np.ones(R.shape), INPUTS, 2, OMEGA[20])
    want = phi_rb @ phi_rb[INPUTS].T
    assert np.linalg.norm(phi @ phi[INPUTS].T - want) / np.linalg.norm(want) < 1e-9
    assert share > 0.999


def test_a_grounded_residual_or_too_few_inputs_gives_no_rigid_body_modes():
    """What a grounded structure leaves below its found modes is residual flexibility (it
    falls as w^2): no mass line is there, which must be said, not fitted. Nor can three
    rigid-body shapes be told apart from two inputs' columns."""
    rng = np.random.default_rng(5)
    B = rng.standard_normal((4, 4))
    R = _mass_line_and_flexibility(np.zeros((4, 1)), 1e-9 * (B @ B.T))
    with pytest.raises(IdentificationError, match="do not show rigid-body modes"):
        fit_rigid_body_modes(OMEGA, R, np.ones(R.shape), INPUTS, 1, OMEGA[20])
    R = _mass_line_and_flexibility(np.eye(4)[:, :3], np.zeros((4, 4)))
    with pytest.raises(IdentificationError, match="need at least as many inputs"):
        fit_rigid_body_modes(OMEGA, R, np.ones(R.shape), INPUTS, 3, OMEGA[20])
