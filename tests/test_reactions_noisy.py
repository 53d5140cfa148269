"""Noisy interface reactions (the report's open problem, section 6.6): the step-1 search.

The case: the payload's 16-DOF Guyan (Z) substructure with Rayleigh damping (2 % at 10 and
1000 Hz), bolted at 4+Z, 8+Z, 18+Z to a flexible stand (``ssid.models.frf_on_test_stand``),
shakers at 11+Z and 16+Z, 512 lines 1-1000 Hz, the report's noise model (2 % magnitude, 2
degree phase, 40 averages, on accelerances, forces and reactions), seeds 1-4. The eight
substructure modes between 10 and 1000 Hz are checked; the three suspension modes below 10 Hz
lie under the noise floor (not determined by these data, docs/replication.md section 6).

Before the high-SNR start, SK from the start the output error liked best stopped far
above the noise's expected cost on every seed (90-1500 times): 5-11 % worst errors, four
modes lost on seed 1.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.correlate import modal_assurance, pair_modes_by_mac
from ssid.frf import FRFData
from ssid.identify import identify_mck
from ssid.models import example_system, frf_on_test_stand
from ssid.models.payload import Z_DOFS, payload_simulator, rayleigh_damping
from ssid.noise import report_noise_frf
from ssid.step1 import Step1Estimate, step1_data
from ssid.step1_refine import errors_in_variables_cost
from ssid.step1_eiv import EIV_COST_FACTOR, reaction_noise_weights
from ssid.tam import guyan_reduce


@pytest.fixture(scope="module")
def stand_case():
    p = payload_simulator()
    sub = guyan_reduce(p.M, p.K, p.index(Z_DOFS))
    C = rayleigh_damping(sub.M, sub.K, 10.0, 1000.0, 0.02)
    frf = frf_on_test_stand(sub.M, C, sub.K, list(Z_DOFS), ["11+Z", "16+Z"],
                            ["4+Z", "8+Z", "18+Z"], np.linspace(1.0, 1000.0, 512))
    lam, phi = sla.eigh(sub.K, sub.M)
    f_hz = np.sqrt(lam) / (2 * np.pi)
    mid = np.flatnonzero((f_hz > 10.0) & (f_hz < 1000.0))
    return frf, f_hz[mid], phi[:, mid]


def test_noisy_reactions_search_ends_at_the_noise_floor(stand_case):
    """Every seed: the search ends within EIV_COST_FACTOR of the number of equations (the
    cost's expected value at the true model), and no in-band mode is lost (MAC >= 0.5). The
    worst-mode error is a noisy statistic (seed 3 puts one mode of the 313/322 Hz close pair
    at 216 Hz, 31 %, at 1.5 times the number of equations, as the other seeds), so its median
    over the seeds is what is asserted: 2.2 % measured (2.3, 2.1, 31, 1.9 %); 7 % before the
    high-SNR start, with four modes lost on seed 1."""
    frf, f_true, phi = stand_case
    n_eq = frf.n_freq * frf.n_out * frf.n_in
    worst = []
    for seed in (1, 2, 3, 4):
        r = identify_mck(report_noise_frf(frf, seed=seed))
        assert r.info["sk"]["cost"] < EIV_COST_FACTOR * n_eq
        pairs = pair_modes_by_mac(modal_assurance(np.asarray(r.mode_shapes), phi), 0.5)
        assert len(pairs) == f_true.size
        worst.append(max(abs(r.natural_freq_hz[p.test] - f_true[p.analysis]) / f_true[p.analysis]
                         for p in pairs))
    assert np.median(worst) < 0.03



@pytest.fixture(scope="module")
def stand8():
    """An 8-DOF substructure on a flexible stand, 400 lines 2-500 Hz, and its true step-1
    matrices (``M^-1 C, M^-1 K, M^-1 D_f, M^-1 D_r``)."""
    M, C, K, dofs = example_system(8, seed=2)
    frf = frf_on_test_stand(M, C, K, dofs, [dofs[2], dofs[5]], [dofs[0], dofs[7]],
                            np.linspace(2, 500, 400))
    Mi = np.linalg.inv(M)
    truth = Step1Estimate(Mi @ C, Mi @ K, Mi[:, frf.input_index()], Mi[:, frf.reaction_index()])
    return frf, truth


def with_gaussian_noise(frf: FRFData, seed: int, flat: float, proportional: float):
    """``frf`` with circular complex Gaussian noise on accelerances and reactions, ``sigma^2 =
    (flat x the FRF's RMS)^2 + (proportional x |H|)^2``; returns (noisy FRFData, sigma_h,
    sigma_r)."""
    rng = np.random.default_rng(seed)

    def noisy(X):
        rms = np.sqrt(np.mean(np.abs(X) ** 2, axis=0, keepdims=True))
        sigma = np.sqrt((flat * rms) ** 2 + (proportional * np.abs(X)) ** 2)
        dx = rng.standard_normal(X.shape) + 1j * rng.standard_normal(X.shape)
        return X + sigma * dx / np.sqrt(2), sigma

    H, s_h = noisy(frf.H)
    Hr, s_r = noisy(frf.H_reaction)
    data = FRFData(freq_hz=frf.freq_hz, H=H, outputs=frf.outputs, inputs=frf.inputs,
                   H_reaction=Hr, reactions=frf.reactions)
    return data, s_h, s_r


def test_errors_in_variables_cost_is_chi_square_at_the_truth(stand8):
    """The cost SK seeks with noisy reactions, at the true substructure: zero on noise-free
    data, and with the noise's own weights ``1/sigma`` its expected value, the number of
    complex equations. Noise model: circular complex Gaussian, flat per FRF at 1 % of the
    FRF's RMS, on accelerances and reactions alike (seed 5). With 400 lines x 8 outputs x 2
    inputs = 6400 equations the cost is a Gamma(6400, 1) variable: mean 6400, std 80 (1.25 %),
    so the band below is +-4 standard deviations."""
    frf, truth = stand8
    assert errors_in_variables_cost(step1_data(frf), truth) < 1e-20
    data, s_h, s_r = with_gaussian_noise(frf, seed=5, flat=0.01, proportional=0.0)
    d = step1_data(data, 1.0 / s_h, 1.0 / s_r)
    n_eq = d.omega.size * d.n * d.n_in
    assert abs(errors_in_variables_cost(d, truth) / n_eq - 1) < 0.05


def test_reaction_noise_levels_recovered_at_the_true_model(stand8):
    """``reaction_noise_weights`` separates accelerance and reaction noise from the equation
    error. Noise model: circular complex Gaussian, sigma^2 = (0.3 % of the FRF's RMS)^2 +
    (1 % of |H|)^2, on both (seed 11), 400 lines on an 8-DOF stand case. Starting from one flat
    level per FRF (off by a factor 3.4 in the median), two rounds at the true model bring every
    value's sigma within a median 3 % (measured); the bound is 10 %."""
    frf, truth = stand8
    data, s_h, s_r = with_gaussian_noise(frf, seed=11, flat=0.003, proportional=0.01)

    def flat(s):
        return np.broadcast_to(1.0 / np.sqrt(np.mean(s**2, axis=0, keepdims=True)), s.shape)

    d = step1_data(data, flat(s_h), flat(s_r))
    assert np.median(np.abs(np.log(d.weight * s_h))) > 1.0
    for _ in range(2):
        d.weight, d.weight_r = reaction_noise_weights(d, truth)
    assert np.median(np.abs(np.log(d.weight * s_h))) < 0.1
    assert np.median(np.abs(np.log(d.weight_r * s_r))) < 0.1


def test_step_1_does_not_use_the_file_variances_with_reactions(stand8):
    """A file with reactions and the variances of its averages (``H_var``, ``H_reaction_var``,
    as acquisition writes them): step 1 is identified from noise levels estimated from the
    data, exactly as without them (measured on the payload on its stand, docs/algorithm.md,
    known limits: the search from the recorded variances lost 7 modes on one seed of four).
    Since stop 62 the refit in physical coordinates of a reaction step 1 cannot determine
    (``ssid.reaction_fit``; 8+Z here) does weight by them, and only with them: so M, C, K
    differ here, and this test holds step 1's estimate, and the refit's use of the variances."""
    frf, _ = stand8
    with_var = report_noise_frf(frf, seed=2, with_variance=True)
    assert with_var.H_var is not None and with_var.H_reaction_var is not None
    r_var = identify_mck(with_var)
    r = identify_mck(report_noise_frf(frf, seed=2))
    assert r_var.info["noise_levels"].startswith("estimated from the data")
    # Step 1 is the same; the physical-coordinates refit of an undetermined reaction
    # (ssid.reaction_fit, 8+Z here) does weight by the stated variances, so M, C, K may differ.
    for a, b in zip(r_var.step1[0].__dict__.values(), r.step1[0].__dict__.values()):
        np.testing.assert_array_equal(a, b)
    assert r_var.info["reaction_fit"]["accepted"] and "reaction_fit" not in r.info
