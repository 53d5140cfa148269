"""Correlation measures: MAC, orthogonality, cross-orthogonality, pairing, FRAC, gap, CMIF."""

from __future__ import annotations

import numpy as np
import pytest
from test_tam_models import beam_model, translations

from ssid.correlate import (
    auto_mac,
    check_orthogonality,
    cross_orthogonality,
    frequency_error_percent,
    modal_assurance,
    orthogonality,
    pair_modes_by_mac,
    pair_modes_by_mac_and_frequency,
    real_mode_from_complex,
)
from ssid.correlate_frf import (
    cmif,
    cmif_peaks,
    cmif_shapes,
    frf_assurance,
    frf_gap,
    frf_gap_db,
    refine_peak_frequencies,
)
from ssid.errors import InputError
from ssid.frf import accelerance
from ssid.modal import modal_damping_matrix
from ssid.tam import guyan_reduce, natural_frequencies_hz, normal_modes


@pytest.fixture(scope="module")
def tam():
    M, K, dofs = beam_model()
    a = translations(dofs, [1, 3, 5, 7, 9, 11])
    red = guyan_reduce(M, K, a)
    _, phi_full = normal_modes(M, K)
    return M, K, a, red, phi_full


def test_mac_of_rescaled_shapes_is_unchanged():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(8, 5)) + 1j * rng.normal(size=(8, 5))
    b = rng.normal(size=(8, 4))
    ref = modal_assurance(a, b)
    sa = rng.normal(size=5) * np.exp(1j * rng.uniform(0, 2 * np.pi, 5)) * 1e5
    sb = rng.choice([-1, 1], 4) * 10 ** rng.uniform(-6, 6, 4)
    # 1e-12: the ratio of products of sums of 8 terms, scaled back, is good to ~1e-15.
    np.testing.assert_allclose(modal_assurance(a * sa, b * sb), ref, atol=1e-12)
    np.testing.assert_allclose(np.diag(auto_mac(a)), 1.0, atol=1e-12)
    assert np.all((ref >= 0) & (ref <= 1))
    # Far from unit scale (a model in odd units) the products' squares would overflow or
    # underflow: the MAC of 1e200 shapes was 0 (QA).
    for scale in (1e-200, 1e200, 1e300):
        np.testing.assert_allclose(modal_assurance(a * scale, b), ref, atol=1e-12)


def test_mac_zero_shape_and_dof_mismatch():
    a = np.array([[1.0, 0.0], [0.0, 0.0]])
    assert modal_assurance(a, a)[1, 1] == 0.0
    with pytest.raises(InputError, match="DOFs"):
        modal_assurance(np.ones((3, 1)), np.ones((4, 1)))


def test_mac_of_1d_shapes_is_one_mode_and_non_finite_shapes_are_refused():
    """A 1-D shape is one mode: MAC([1, 0, 0], [0.5, 1, 0]) = 0.5^2 / (1 * 1.25) = 0.2 (it was
    read as 3 modes of 1 DOF: a 3 x 3 matrix of 1s and 0s). A NaN or Inf in a shape gave a MAC
    of 0 without a word (QA)."""
    a, b = np.array([1.0, 0.0, 0.0]), np.array([0.5, 1.0, 0.0])
    mac = modal_assurance(a, b)
    assert mac.shape == (1, 1) and mac[0, 0] == pytest.approx(0.2, abs=1e-15)
    np.testing.assert_array_equal(modal_assurance(a, np.column_stack([b, a])), [[mac[0, 0], 1.0]])
    assert auto_mac(b).shape == (1, 1)
    r = real_mode_from_complex(b * np.exp(0.7j))  # one complex mode back to (n, 1)
    assert r.shape == (3, 1) and modal_assurance(r, b)[0, 0] == pytest.approx(1.0, abs=1e-15)
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(InputError, match="phi_a holds NaN or Inf in 1 value\\(s\\), first at DOF 1 of mode 1"):
            modal_assurance(np.array([[bad], [1.0], [0.0]]), b)
        with pytest.raises(InputError, match="phi_b holds NaN or Inf"):
            modal_assurance(b, np.array([0.0, bad, 1.0]))
    with pytest.raises(InputError, match="shape vector or \\(n_dof, n_modes\\) array"):
        modal_assurance(np.ones((3, 1, 1)), b)


def test_cross_orthogonality_of_a_model_with_itself_is_identity(tam):
    _, _, _, red, _ = tam
    _, phi = normal_modes(red.M, red.K)
    rng = np.random.default_rng(5)
    s = rng.choice([-1, 1], phi.shape[1]) * rng.uniform(0.1, 10, phi.shape[1])
    xo = cross_orthogonality(phi * s, phi, red.M)
    np.testing.assert_allclose(np.abs(xo), np.eye(phi.shape[1]), atol=1e-10)
    chk = check_orthogonality(xo)
    assert chk.passed and chk.max_offdiag < 1e-10 and chk.min_diag > 1 - 1e-10
    np.testing.assert_allclose(orthogonality(phi * s, red.M), np.eye(phi.shape[1]), atol=1e-10)


def test_fem_modes_against_the_guyan_tam_mass_meet_the_criterion(tam):
    # The full model's lower modes at the a-set, with the Guyan TAM mass: near-orthogonal
    # (the report's check, off-diagonal < 0.1) because Guyan is accurate for them.
    _, _, a, red, phi_full = tam
    O = orthogonality(phi_full[a, :4], red.M)
    chk = check_orthogonality(O, diag_min=0.0)
    assert chk.passed, chk
    # A badly wrong "test" mode (two modes mixed) fails the criterion.
    mixed = phi_full[a, :4].copy()
    mixed[:, 1] = phi_full[a, 1] + 0.6 * phi_full[a, 2] / np.abs(phi_full[a, 2]).max() * np.abs(phi_full[a, 1]).max()
    assert not check_orthogonality(orthogonality(mixed, red.M), diag_min=0.0).passed


def test_pairing_is_one_to_one_and_drops_poor_matches():
    mac = np.array([[0.95, 0.90, 0.0], [0.97, 0.2, 0.0], [0.0, 0.1, 0.3]])
    pairs = pair_modes_by_mac(mac, min_mac=0.5)
    # Row-wise maxima would give both test modes 1 and 2 analysis mode 1; the assignment
    # gives test 1 -> analysis 2, test 2 -> analysis 1, and test 3 has no match.
    assert [(p.test, p.analysis) for p in pairs] == [(0, 1), (1, 0)]
    np.testing.assert_allclose(frequency_error_percent([10.5, 9.0], [10.0, 10.0]), [5.0, -10.0])


def test_pairing_ignores_correlations_below_the_threshold():
    """Seen on a 16-DOF model: test mode 0 matches analysis mode 0 exactly (1.0) and another
    weakly (0.42); test mode 1 resembles analysis mode 0 (0.9) only. Counting the 0.42 in the
    sum, the assignment gave analysis mode 0 to test mode 1 (0.9 + 0.42 > 1.0) and dropped
    the exact pair."""
    mac = np.array([[1.0, 0.42], [0.9, 0.0]])
    pairs = pair_modes_by_mac(mac, min_mac=0.5)
    assert [(p.test, p.analysis) for p in pairs] == [(0, 0)]


def test_pairing_by_mac_and_frequency_tells_aliased_modes_apart():
    """Two reference modes look alike at the sensors (MAC 0.9 with each other's test mode);
    MAC alone pairs the 1.3 Hz test mode with the 800 Hz reference mode, the frequencies set
    it right; a test mode with MAC < 0.5 to every reference mode stays unpaired."""
    mac = np.array([[0.9, 0.95, 0.0], [0.95, 0.9, 0.0], [0.0, 0.0, 0.4]])
    f_test = np.array([1.3, 805.0, 50.0])
    f_ref = np.array([1.29, 800.0, 50.0])
    by_mac = pair_modes_by_mac(mac, 0.5)
    assert [(p.test, p.analysis) for p in by_mac] == [(0, 1), (1, 0)]
    pairs = pair_modes_by_mac_and_frequency(mac, f_test, f_ref, 0.5)
    assert [(p.test, p.analysis, p.mac) for p in pairs] == [(0, 0, 0.9), (1, 1, 0.9)]
    # The 1.29 Hz reference mode's counterpart missing, and the 805 Hz test mode a poor match
    # (0.3) of its own: left over, it is not the 1.29 Hz mode's pair however alike the shapes.
    left = np.array([[0.95, 0.3]])
    assert [(p.test, p.analysis) for p in pair_modes_by_mac(left, 0.5)] == [(0, 0)]
    assert pair_modes_by_mac_and_frequency(left, [805.0], [1.29, 800.0], 0.5) == []


def test_real_mode_from_complex_recovers_a_rotated_normal_mode():
    phi = np.array([1.0, -2.0, 0.5])
    z = phi * 3.0 * np.exp(1j * 0.7)
    r = real_mode_from_complex(z[:, None])[:, 0]
    np.testing.assert_allclose(np.abs(r @ phi) / (np.linalg.norm(r) * np.linalg.norm(phi)), 1.0, atol=1e-12)


@pytest.fixture(scope="module")
def frfs():
    M, K, dofs = beam_model(n_elem=4)
    C = modal_damping_matrix(M, K, np.full(M.shape[0], 0.02))
    out = translations(dofs, [1, 2, 3, 4, 5])
    S = np.eye(M.shape[0])[out]
    D = S.T[:, [0, 4]]
    f = np.linspace(2.0, 600.0, 2400)
    H = accelerance(M, C, K, 2 * np.pi * f, D, S)
    return f, H, M, K, out


def test_frac_and_gap(frfs):
    _, H, *_ = frfs
    np.testing.assert_allclose(frf_assurance(H, H), 1.0, atol=1e-12)
    assert frf_gap(H, H) == pytest.approx(0.0, abs=1e-12)
    # A 10 % calibration error: FRAC cannot see a constant factor, the gap does.
    G = 1.1 * H
    np.testing.assert_allclose(frf_assurance(H, G), 1.0, atol=1e-12)
    assert frf_gap(H, G) == pytest.approx(np.log(1.1), rel=1e-9)
    assert frf_gap_db(H, G) == pytest.approx(20 * np.log10(1.1), rel=1e-9)
    # A frequency shift lowers FRAC below 1.
    assert np.nanmax(frf_assurance(H[:-40], H[40:])) < 0.9
    # Nor does FRAC depend on a scale far from 1 (it was NaN from overflow at 1e200).
    np.testing.assert_allclose(frf_assurance(H, 1e200 * G), 1.0, atol=1e-12)
    np.testing.assert_allclose(frf_assurance(1e-200 * H, H[::-1]), frf_assurance(H, H[::-1]), atol=1e-12)


def test_blanked_values_are_skipped(frfs):
    _, H, *_ = frfs
    Hn = H.copy()
    valid = np.ones(H.shape, dtype=bool)
    Hn[100, 1, 0] = np.nan
    Hn[200, 2, 1] = 1e9  # garbage, but marked invalid
    valid[100, 1, 0] = valid[200, 2, 1] = False
    assert frf_gap(Hn, H, valid) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(frf_assurance(Hn, H, valid), 1.0, atol=1e-12)
    assert np.all(np.isfinite(cmif(Hn, valid)))


def test_cmif_finds_the_modes_and_their_shapes(frfs):
    f, H, M, K, out = frfs
    sv = cmif(H)
    assert sv.shape == (f.size, 2) and np.all(np.diff(sv, axis=1) <= 0)
    peaks = cmif_peaks(f, sv)
    f_n = natural_frequencies_hz(M, K)
    f_n = f_n[f_n < f[-1]]
    fp = refine_peak_frequencies(f, sv[:, 0], peaks)
    assert fp.size == f_n.size
    # Accelerance peaks of 2 % damped modes sit ~zeta^2 above f_n; interpolation between
    # 0.25 Hz lines: within 0.5 %.
    np.testing.assert_allclose(fp, f_n, rtol=5e-3)
    _, phi = normal_modes(M, K)
    mac = modal_assurance(cmif_shapes(H, peaks), phi[out, : f_n.size])
    assert np.all(np.diag(mac) > 0.99)


def test_an_analysis_mode_at_rest_at_every_test_dof_has_mac_zero_and_is_named():
    """Fixed-fixed 7-mass chain (1 kg, 1e4 N/m) measured at masses 2, 4 and 6, the nodes of
    its mode 4 (sin(4 pi j / 8)): the mode's partition there is round-off, which the MAC,
    scale-free, took to unit length and correlated (0.44, 0.06, 0.60 with the test modes: a
    pair above 0.5 was possible). It is MAC 0 now, and a warning says why. The test model is
    the chain's Guyan TAM, whose modes at these DOFs are the chain's modes 1-3 (sines), so those
    still pair, with MAC 1 (1e-12: round-off of 3 x 3 eigenpairs)."""
    from ssid.correlate_models import correlate_models
    from ssid.io import Model

    n = 7
    K = 1e4 * (2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    dofs = [f"{i}+Z" for i in range(1, n + 1)]
    red = guyan_reduce(np.eye(n), K, [1, 3, 5])
    study = correlate_models(Model(red.M, red.K, None, ["2+Z", "4+Z", "6+Z"]), Model(np.eye(n), K, None, dofs))
    assert study.analysis_freq_hz.size >= 4
    np.testing.assert_array_equal(study.mac[:, 3], 0.0)
    assert study.warnings == ["analysis mode 4 is at rest at every test DOF (a node at each): not observable by "
                              "this test, MAC 0 with every test mode"]
    assert [(p.test, p.analysis) for p in study.pairs][:1] == [(0, 0)]
    assert study.pairs[0].mac == pytest.approx(1.0, abs=1e-12)
