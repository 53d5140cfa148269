"""Step-1 starts fitted above the lowest lines (``ssid.step1.starts_above_low_lines``).

Under noise the equation error over all lines is ruled by the lowest ones; on the payload's
10-DOF model at 1-300 Hz the refinement from the best all-line start ended far above the
record's minimum with targets above the band missed (``bench/noisy_basins.py``).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from conftest import uniform_chain

from ssid.correlate import modal_assurance, pair_modes_by_mac_and_frequency
from ssid.frf import accelerance_from_model
from ssid.identify import identify_mck, identify_step1
from ssid.modal import root_frequency_damping
from ssid.models.payload import INTERFACE_DOFS, modal_damping, payload_simulator, target_modes
from ssid.noise import report_noise_frf, roughness_weights
from ssid.step1 import estimate_equation_error, starts_above_low_lines, step1_data
from ssid.step1_refine import output_error_cost
from ssid.step2 import state_space_modes


def test_each_start_is_exact_on_noise_free_full_order_data():
    """Eq. 3.7 holds exactly at every line of a full-order model's noise-free data, so a fit
    to any subset of lines recovers M^-1 C and M^-1 K to rounding: the cut changes which
    lines, not what is fitted. 1-300 Hz: cuts at 5, 20 and 60 Hz."""
    M, C, K = uniform_chain()
    dofs = ["1", "2", "3", "4"]
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(1, 300, 400), dofs, ["4"])
    starts = starts_above_low_lines(step1_data(frf))
    assert sorted(starts) == ["stls>20Hz", "stls>5Hz", "stls>60Hz"]
    for est in starts.values():
        assert np.allclose(est.K_hat, K, rtol=0, atol=1e-6 * np.abs(K).max())
        assert np.allclose(est.C_hat, C, rtol=0, atol=1e-6 * np.abs(C).max())


def test_no_start_when_a_cut_leaves_out_no_line_or_too_many():
    M, C, K = uniform_chain()
    dofs = ["1", "2", "3", "4"]
    # 100-300 Hz: every cut (5, 20, 60 Hz) lies below the first line.
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(100, 300, 50), dofs, ["4"])
    assert starts_above_low_lines(step1_data(frf)) == {}
    # 1-300 Hz in 10 lines: above 60 Hz 8 lines, 16 real equations for p = 9 unknowns: kept;
    # a cut at 0.9 f_max keeps 1 line (2 equations): left out.
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(1, 300, 10), dofs, ["4"])
    assert list(starts_above_low_lines(step1_data(frf), cuts=(1 / 5, 0.9))) == ["stls>60Hz"]


def test_noisy_payload_holds_the_targets_above_the_band(payload_10dof_300hz):
    """The 10-DOF payload model (EfI sensors, docs/replication.md), 1-300 Hz, 512 lines, the
    report's noise (2 % magnitude, 2 degrees phase, 40 averages on response and force), seed 1.
    Seven target modes lie in the band, three above it (318.6, 395.2 and 558.8 Hz). From the
    all-line starts the refinement ended with all three missed; with the starts above the low
    lines its output error is over ten times lower (82 times measured) and every target is
    paired with an identified mode by MAC >= 0.5 and frequency. The in-band ones are within
    0.1 % (0.02 % measured); the one at 1.9 times the band's edge is the data's weakest
    (measured 14 % off, 5 % after the search above the band) and is only required to be
    paired."""
    p = payload_simulator()
    frf = report_noise_frf(payload_10dof_300hz[0], seed=1)
    sensors = frf.outputs

    # The search above the band (tests/test_step1_above_band_search.py) left out of both.
    est, d, _ = identify_step1(frf, search_above_band=False)
    old, _, _ = identify_step1(frf, low_line_starts=False, search_above_band=False)
    assert output_error_cost(d, old) > 10 * output_error_cost(d, est)

    r = identify_mck(frf)
    lam, phi = sla.eigh(p.K, p.M)
    tm = target_modes(p, 10)
    f_t = np.sqrt(lam[tm]) / (2 * np.pi)
    phi_t = phi[p.index(sensors)][:, tm]
    pairs = pair_modes_by_mac_and_frequency(modal_assurance(r.mode_shapes, phi_t), r.natural_freq_hz, f_t, 0.5)
    assert len(pairs) == 10
    err = {pr.analysis: abs(r.natural_freq_hz[pr.test] / f_t[pr.analysis] - 1) for pr in pairs}
    assert max(err[a] for a in range(10) if f_t[a] < 300) < 1e-3


def test_the_low_line_start_competes_after_sk_not_before():
    """12-DOF payload (EfI sensors), 1-650 Hz, the report's noise, seed 3. The low-line start
    is far lower in output error than the all-line ones before any refinement (as it always
    is); refined to the end from it the fit ended 1.3 times higher with a target more missed.
    After SK (1.7 times higher measured) the all-line start is kept, and the step-1 roots hold
    the ten targets in the band (the two above it, 992 and 1124 Hz, are missed either way:
    section 3 of docs/replication.md)."""
    p = payload_simulator()
    C = modal_damping(p.M, p.K, 0.02)
    sensors = ["1+Z", "2+Z", "3+Z", "4+Z", "5+Z", "6+Z", "7+Z", "8+Z", "12+Z", "15+Z", "17+Z", "18+Z"]
    frf = report_noise_frf(
        accelerance_from_model(p.M, C, p.K, p.dofs, np.linspace(1, 650, 512), sensors, INTERFACE_DOFS), seed=3)
    est, _, info = identify_step1(frf)
    low = info["sk_low_lines"]
    assert info["start"] in ("ls", "tls", "stls") and low["cost"] > info["sk"]["cost"]
    # The starts as step 1 ranks them: with the FRFs' roughness as their noise levels.
    d = step1_data(frf)
    d.weight = roughness_weights(d.H, frf.valid_mask())
    low_start = starts_above_low_lines(d)[low["start"]]
    assert all(output_error_cost(d, low_start) < output_error_cost(d, e)
               for e in (estimate_equation_error(d, k) for k in ("ls", "tls", "stls")))

    lam, phi = sla.eigh(p.K, p.M)
    tm = target_modes(p, 12)
    f_t = np.sqrt(lam[tm]) / (2 * np.pi)
    m = state_space_modes(est.C_hat, est.K_hat)
    wn, _ = root_frequency_damping(m.lam[: m.n_pairs])
    pairs = pair_modes_by_mac_and_frequency(
        modal_assurance(m.theta[: m.n, : m.n_pairs], phi[p.index(sensors)][:, tm]), wn / (2 * np.pi), f_t, 0.5)
    assert {pr.analysis for pr in pairs} >= {a for a in range(12) if f_t[a] < 650}
