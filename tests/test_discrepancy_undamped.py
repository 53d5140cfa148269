"""The discrepancy workflow on a model file without C (``ssid.discrepancy.undamped``).

Such a model gets modal damping, one ratio for every mode, fitted as a nuisance. A mass or a
spring changes the structure, and its damping can then be read two ways: the nominal modes'
damping matrix kept, or every mode of the changed structure damped alike. The data decide.

Noise model of the chain tests: each FRF value times ``1 + 0.001 (n_1 + j n_2) / sqrt(2)``,
``n`` standard normal (seed 1), no ``H_var`` (the weights come from the FRFs' roughness).
At 0.1 % the two readings differ by far more than the noise (the wrong one leaves a gap of 7).
"""

from __future__ import annotations

import numpy as np
import pytest

from ssid.discrepancy import find_discrepancy
from ssid.discrepancy.cases import make_case
from ssid.discrepancy.damping import peak_damping_ratios
from ssid.discrepancy.response import unit_modal_damping
from ssid.frf import accelerance_from_model
from ssid.io import Model
from ssid.models.payload import Z_DOFS, modal_damping, payload_simulator
from ssid.tam import normal_modes

ZETA, ADDED_KG = 0.02, 0.2
DOFS = ["1", "2", "3"]
CHAIN_M = np.eye(3)
CHAIN_K = 1e5 * np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 1]])  # grounded at DOF 1: 22-90 Hz


def _chain_test(own_modes: bool):
    """The three-mass chain with 0.2 kg added at the unmeasured DOF 3, measured at DOFs 1
    and 2 (input at 1), 10-400 Hz: damped in its own modes, or with the nominal C kept."""
    M2 = CHAIN_M.copy()
    M2[2, 2] += ADDED_KG
    C = ZETA * unit_modal_damping(M2 if own_modes else CHAIN_M, CHAIN_K)
    frf = accelerance_from_model(M2, C, CHAIN_K, DOFS, np.geomspace(10, 400, 400), ["1", "2"], ["1"])
    rng = np.random.default_rng(1)
    frf.H = frf.H * (1 + 1e-3 * (rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape))
                     / np.sqrt(2))
    return find_discrepancy(Model(M=CHAIN_M, K=CHAIN_K, C=None, dofs=DOFS), frf)


def _modal_damping_ratios(model: Model) -> np.ndarray:
    lam, phi = normal_modes(model.M, model.K)
    return np.diag(phi.T @ model.C @ phi) / (2 * np.sqrt(lam))


def test_a_mass_on_a_structure_damped_in_its_own_modes_is_named_a_mass():
    """Before the own-modes reading: an oscillator of 0.1998 kg tuned to 1100 Hz, far above
    the band, stood in for the mass, gap 752 -> 7.05 (the mass: 7.09)."""
    res = _chain_test(own_modes=True)
    assert (res.effect.name, res.dofs) == ("added_mass", ["3"])
    assert res.parameters["mass_kg"] == pytest.approx(ADDED_KG, rel=0.01)
    assert res.gap_after < 1.3  # the truth leaves 1.13 here
    assert res.info["residual"]["closed"]
    assert "every mode of the changed structure damped alike" in res.info["damping_source"]
    # the updated model has the damping it was judged with: every mode at the measured ratio
    assert _modal_damping_ratios(res.updated_model) == pytest.approx(np.full(3, ZETA), rel=0.02)


def test_the_nominal_modes_damping_is_kept_when_the_data_show_it():
    res = _chain_test(own_modes=False)
    assert (res.effect.name, res.dofs) == ("added_mass", ["3"])
    assert res.parameters["mass_kg"] == pytest.approx(ADDED_KG, rel=0.01)
    assert res.gap_after < 1.3
    assert "changed structure" not in res.info["damping_source"]
    ratio = res.updated_model.C / unit_modal_damping(CHAIN_M, CHAIN_K)  # the nominal modes' C, scaled
    assert ratio == pytest.approx(np.full((3, 3), ZETA), rel=0.02)


def test_model_without_c_gets_fitted_modal_damping():
    case = make_case(1003, structure="payload", effect="added_mass", undamped_nominal=True, n_lines=400)
    assert case.nominal.C is None
    res = find_discrepancy(case.nominal, case.frf)
    assert (res.effect.name, set(res.dofs)) == (case.truth.name, set(case.truth.dofs))
    assert res.parameters["mass_kg"] == pytest.approx(case.truth.parameters["mass_kg"], rel=0.1)
    assert "no C" in res.info["damping_source"]
    assert res.updated_model.C is not None  # written with the damping used for gap_after


def test_damping_read_off_the_measured_peaks():
    pm = payload_simulator()
    C = modal_damping(pm.M, pm.K, 0.02)
    frf = accelerance_from_model(pm.M, C, pm.K, pm.dofs, np.linspace(20, 650, 1000), list(Z_DOFS), ["4+Z", "12+Z"])
    _, zeta = peak_damping_ratios(frf.freq_hz, frf.H, np.ones(frf.H.shape, bool))
    assert zeta.size >= 4
    assert np.median(zeta) == pytest.approx(0.02, rel=0.1)


def test_modes_damped_unlike_each_other_are_warned_of():
    """Mass-proportional damping (zeta 5 % at 22 Hz to 1.2 % at 90 Hz) measured against the
    model without C: one ratio for every mode cannot describe it, and the warning says the
    effect named may stand in for damping (a QA run on a payload on its stand, the stand's
    dashpot lost with C, named oscillators and flagged channel gains without one)."""
    lam, _ = normal_modes(CHAIN_M, CHAIN_K)
    alpha = 2 * 0.05 * np.sqrt(lam[0])
    frf = accelerance_from_model(CHAIN_M, alpha * CHAIN_M, CHAIN_K, DOFS, np.geomspace(10, 400, 400), ["1", "2"],
                                 ["1"])
    res = find_discrepancy(Model(M=CHAIN_M, K=CHAIN_K, C=None, dofs=DOFS), frf)
    assert any("one ratio for every mode cannot describe them" in w for w in res.info["warnings"])
    assert not any("cannot describe them" in w for w in _chain_test(own_modes=True).info["warnings"])
