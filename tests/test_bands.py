"""Band processing (report section 5.2) on a system with known M, C, K."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ssid.band_criteria import (
    cluster_repeated,
    phase_seen_by_lines,
    pick_representatives,
    reject_edge_cut_only,
    reject_inside_resolved,
    resonance_cut_by_band_edge,
)
from ssid.band_select import default_band_width_hz
from ssid.bands import (
    BandRoot,
    band_min_lines,
    default_bands,
    distance_to_nearest_line,
    fit_scale_factors,
    frf_share,
    line_spacing_at,
    normal_mode_mck,
    overlapping_bands,
    plot_band_roots,
    process_bands,
    repeat_tolerance_hz,
    residual_runs,
    scale_selected_roots,
)
from ssid.frf import accelerance_from_model
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system
from ssid.models.payload import modal_damping
from ssid.noise import report_noise_frf


@pytest.fixture(scope="module")
def case():
    M, C, K, dofs = example_system(8, seed=2)  # modes 14.5 ... 477 Hz
    lam, _ = complex_modes(M, C, K)
    f_true = root_frequency_damping(lam)[0] / (2 * np.pi)
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(5, 520, 600), dofs, [dofs[1], dofs[5]])
    return M, C, K, f_true, frf


def test_overlapping_bands_cover_every_line_twice():
    bands = overlapping_bands(5.0, 520.0, 150.0, 0.5)
    f = np.linspace(5, 520, 1000)
    cover = sum(((f >= lo) & (f <= hi)).astype(int) for lo, hi in bands)
    assert cover.min() >= 2


def test_noise_free_bands_find_every_mode_and_bp3_is_exact(case, tmp_path):
    M, C, K, f_true, frf = case
    res = process_bands(frf, overlapping_bands(5, 520, 150, 0.5), solver="ls")
    assert np.allclose(res.freq_hz, f_true, rtol=1e-6)
    u, mck = scale_selected_roots(frf, res, "BP3")
    assert mck is not None
    assert np.linalg.norm(mck[0] - M) / np.linalg.norm(M) < 1e-6
    assert np.linalg.norm(mck[2] - K) / np.linalg.norm(K) < 1e-6
    plot_band_roots(str(tmp_path / "bands.png"), res, f_true)
    assert (tmp_path / "bands.png").stat().st_size > 0


def test_noisy_bands_keep_true_modes_and_reject_noise_modes(case):
    """Report noise model, seed 4: the four criteria reject every computational root (each
    criterion fires at least once) and keep exactly the eight true modes."""
    M, C, K, f_true, frf = case
    noisy = report_noise_frf(frf, seed=4)
    res = process_bands(noisy, overlapping_bands(5, 520, 150, 0.5))
    assert res.freq_hz.size == f_true.size
    assert np.max(np.abs(res.freq_hz - f_true) / f_true) < 1e-3
    fired = {r.rejected for r in res.roots}
    assert {"outside band", "negative damping", "low MPC", "not repeated"} <= fired
    for method in ("BP1", "BP2", "BP3"):
        _, mck = scale_selected_roots(noisy, res, method)
        assert np.linalg.norm(mck[2] - K) / np.linalg.norm(K) < 0.03, method


# --- BP2 / BP3 assembly of M, C, K (report section 5.2, Eqs. 3.23, 3.26) ---------------------
#
# A 10-DOF spring-mass chain (modal damping, 2 %) seen by 5 sensors over a range holding 7 of
# its modes: more modes in the data than the reduced model can hold, as on the payload (22
# modes, 16 sensors). The reduced model that holds the 5 lowest modes exactly is known:
# with Phi_s the sensor rows of the mass-normalised modes, M^-1 = Phi_s Phi_s^T and
# K^-1 = Phi_s diag(1/omega^2) Phi_s^T (the partitions of A_s^-1, B_s^-1 of Eq. 3.26).


# --- Criterion 4 and the line spacing (report section 5.2) ----------------------------------


def test_repeat_tolerance_is_a_fraction_of_the_width_that_locates_the_root():
    """1/8 of max(2 zeta f, d), d the distance to the nearest line: 0.5 % of f for a resolved
    2 %-damped mode, d/8 for a mode narrower than the line spacing (the 1.29 Hz suspension
    mode, 0.29 Hz above the 1 Hz line of a 2.25 Hz grid: 2.8 % of f), and tighter than 0.5 %
    of f for a lightly damped root."""
    lines = 1.0 + 2.25 * np.arange(1000)
    f = np.array([1001.0, 1.29, 1001.0])
    d = distance_to_nearest_line(lines, f)
    assert np.allclose(d, [1.0, 0.29, 1.0])  # the lines at 1000 and 1 Hz
    tol = repeat_tolerance_hz(f, np.array([0.02, 0.02, 3e-4]), d)
    assert np.allclose(tol, [0.005 * 1001.0, 0.29 / 8, 1.0 / 8])


def _root(band, f, zeta):
    w = 2 * np.pi * f
    lam = complex(-zeta * w, w * np.sqrt(1 - zeta**2))
    return BandRoot(band, lam, np.ones(2, dtype=complex), f, zeta, 1.0)


def test_repeat_criterion_keeps_unresolved_mode_and_rejects_noise_roots():
    """Roots as band processing found them on the 16-DOF payload, 1-2300 Hz, df = 2.25 Hz,
    with the report's noise (seed 1). The 1.29 Hz suspension mode (2 zeta f = 0.05 Hz, far
    below df) is estimated at 1.272 and 1.290 Hz in bands 0 and 1, 1.4 % apart: within d/8
    (d = 0.27-0.29 Hz to the 1 Hz line), the same mode. Band 0 also holds a noise root at
    1.186 Hz, 0.10 Hz from the band-1 estimate: beyond d/8 (it was within df/8 = 0.28 Hz, and
    only the closest-first matching left it alone then). Near 2200 Hz band 22 holds a noise
    root (2196.3 Hz, zeta 1.2 %) beside its estimate of the mode (2200.3 Hz), both within
    tolerance of the other bands' estimates: the closest pairs are matched first and the
    mode's estimates of bands 21, 22, 23 form the group. Two lightly damped noise roots 0.5
    Hz apart near 1000 Hz (within 0.5 % of f, the old tolerance) are more than
    max(2 zeta f, d)/8 apart and are rejected."""
    roots = [_root(0, 1.186, 0.0172), _root(0, 1.272, 0.0204), _root(1, 1.290, 0.0211),
             _root(22, 2196.324, 0.0118), _root(22, 2200.294, 0.0200),
             _root(21, 2200.853, 0.0196), _root(23, 2201.743, 0.0199),
             _root(9, 1000.0, 3e-4), _root(10, 1000.5, 3e-4)]
    cluster_repeated(roots, 0.125, np.linspace(1.0, 2300.0, 1024))  # df = 2.25 Hz
    kept = [r.freq_hz for r in roots if not r.rejected]
    assert kept == [1.272, 1.290, 2200.294, 2200.853, 2201.743]
    assert roots[1].cluster == roots[2].cluster
    assert len({r.cluster for r in roots[4:7]}) == 1
    # Representatives: the estimate farthest from an edge of its band inside the record, band
    # 1 (1-201 Hz) for the 1.29 Hz mode, band 22 (2101-2300 Hz) for the 2200 Hz one (2200.853
    # Hz is 0.15 Hz below the edge of band 21, 2001-2201 Hz).
    bands = overlapping_bands(1.0, 2300.0, 200.0, 0.5)
    assert bands[1] == (1.0, 201.0) and bands[22] == (2101.0, 2300.0)
    reps = pick_representatives(roots, bands)
    assert [r.freq_hz for r in reps] == [1.290, 2200.294]


def test_damping_check_skipped_where_no_line_sees_the_damping():
    """Roots as band processing found them on the payload (12 sensors, 1-1158 Hz, 512 lines,
    the report's noise, seed 2; the record-level test below): the 1.29 Hz suspension mode at
    1.2793 Hz with damping -0.32 % in band 0 and 1.2797 Hz with 1.95 % in band 1. The nearest
    line (1 Hz) is 0.28 Hz away, 11 half-widths zeta f: the lines see neither the phase nor
    the damping, sign included. The two are one mode (criterion 4 skips its factor-2 damping
    check), represented by the estimate with positive damping. Were the lines to see them,
    the damping check would keep them apart and neither would be repeated. (Whether the
    record gives a negative estimate depends on where its step-1 fits stop: with a
    gain-ratio LM schedule it gave none. This test holds the rule itself.)"""
    lines = np.linspace(1.0, 1158.0, 512)
    roots = [_root(0, 1.27932, -0.0032), _root(1, 1.27971, 0.0195)]
    for r in roots:
        r.phase_seen = phase_seen_by_lines(r.freq_hz, r.zeta, lines)
    assert not any(r.phase_seen for r in roots)
    cluster_repeated(roots, 0.125, lines)
    assert not any(r.rejected for r in roots) and roots[0].cluster == roots[1].cluster >= 0
    bands = overlapping_bands(1.0, 1158.0, default_band_width_hz(lines), 0.5)
    assert [r.freq_hz for r in pick_representatives(roots, bands)] == [1.27971]
    seen = [replace(r, phase_seen=True, cluster=-1) for r in roots]
    cluster_repeated(seen, 0.125, lines)
    assert [r.rejected for r in seen] == ["not repeated"] * 2


@pytest.mark.parametrize("seed, noise", [
    (10, [(6, 321.89400, 0.00024), (7, 321.93359, 0.00006)]),
    (19, [(6, 322.35805, 0.0018), (7, 322.40757, 0.0017)])])
def test_unresolved_mode_inside_a_resolved_modes_half_power_band_is_rejected(seed, noise):
    """Roots as band processing found them on the payload (12 sensors, 1-1158 Hz, df = 2.26
    Hz, the report's noise; the record-level test below): bands 6 and 7 hold the 318.57 Hz
    mode (zeta 2 %: half-power band +-6.4 Hz, 12.7 Hz wide, resolved) and a root 3.3 Hz (seed
    10) or 3.8 Hz (seed 19) above it, with damping 0.006-0.18 %, repeated in both bands:
    unresolved, inside the mode's half-power band, it is rejected with its repeat. Kept: the
    suspension modes (1.29 and 2.83 Hz, unresolved, no resolved mode near), an unresolved
    root 7 Hz above the mode (outside its half-power band) and a 2 % root 4 Hz below it
    (resolved: a close pair, not noise on one resonance)."""
    lines = np.linspace(1.0, 1158.0, 512)
    bands = overlapping_bands(1.0, 1158.0, default_band_width_hz(lines), 0.5)
    assert bands[6] == pytest.approx((242.0, 338.5), abs=0.1)
    roots = [_root(6, 318.56356, 0.0200), _root(7, 318.57253, 0.0200)]
    roots += [_root(*r) for r in noise]
    roots += [_root(0, 1.287, 0.0200), _root(1, 1.288, 0.0195), _root(0, 2.830, 0.0200),
              _root(1, 2.831, 0.0198), _root(6, 325.60, 0.0005), _root(7, 325.61, 0.0005),
              _root(6, 314.5, 0.0200), _root(7, 314.5, 0.0201)]
    for r in roots:
        r.phase_seen = phase_seen_by_lines(r.freq_hz, r.zeta, lines)
    cluster_repeated(roots, 0.125, lines)
    assert all(r.cluster >= 0 for r in roots)  # every one repeated: criterion 4 keeps them all
    reject_inside_resolved(roots, bands, lines)
    verdict = {r.freq_hz: r.rejected for r in roots}
    assert all(verdict[f] == "inside a resolved mode's half-power band" for _, f, _ in noise)
    assert [f for f, v in verdict.items() if v] == [f for _, f, _ in noise]


def test_residual_terms_dropped_only_where_a_mode_is_unresolved():
    """A run of lines 1 Hz apart around a mode with 2 zeta f = 0.05 Hz gets no residual terms,
    a run around a mode with 2 zeta f = 4 Hz keeps them."""
    w = 2 * np.pi * np.concatenate([np.arange(1.0, 8.0), np.arange(95.0, 106.0)])
    seg = np.concatenate([np.zeros(7, int), np.ones(11, int)])
    lam = np.array([_root(0, 1.29, 0.02).lam, _root(0, 100.0, 0.02).lam])
    assert residual_runs(w, seg, lam) == {0: False, 1: True}


def test_bp3_scale_factors_of_a_low_mode_come_from_its_own_lines():
    """A 6-DOF chain on a soft spring (modes 1.20, 23.9 ... 99.4 Hz, modal damping 2 %),
    every DOF measured, 150 lines over 1-150 Hz (df = 1 Hz: the 1.2 Hz mode is unresolved),
    the report's noise model (2 % of each FRF's RMS magnitude, 2 degrees, uniform, 40
    averages), seeds 1-3. Exact roots, shapes perturbed by a complex 1e-3 (as noisy bands
    give), lines within 3 half-power bands of each mode (BP3). With every mode fitted on every
    run (``local=False``) the lines far above the 1.2 Hz mode weigh in on its scale factor
    through the part of its tail the residual terms cannot take; with ``local=True`` M is within
    5e-3 of the true M (measured 2.5e-3 to 4.1e-3, against 4.7e-3 to 1.8e-2) and K within 5e-3."""
    from ssid.band_scaling import _near_resonance, _subset
    from ssid.noise import frf_noise_weights
    from ssid.step1 import step1_data

    n = 6
    m = np.array([2.0, 1.2, 0.9, 1.1, 1.0, 0.8])  # kg
    k = 1e5 * np.array([0.004, 1.5, 0.8, 1.2, 1.1, 0.9])  # N/m, spring 0 to ground
    K = np.zeros((n, n))
    K[0, 0] = k[0]
    for i in range(1, n):
        K[i - 1:i + 1, i - 1:i + 1] += k[i] * np.array([[1.0, -1.0], [-1.0, 1.0]])
    M = np.diag(m)
    C = modal_damping(M, K, 0.02)
    dofs = [str(i) for i in range(n)]
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(1.0, 150.0, 150), dofs, ["0", "3"])
    lam, th = complex_modes(M, C, K)
    wn, zeta = root_frequency_damping(lam)
    roots = [_root(0, w / (2 * np.pi), z) for w, z in zip(wn, zeta)]
    assert 2 * zeta[0] * wn[0] / (2 * np.pi) < 0.1  # unresolved by 1 Hz lines
    for seed in (1, 2, 3):
        noisy = report_noise_frf(frf, seed=seed)
        d = step1_data(noisy, frf_noise_weights(noisy))
        d = _subset(d, _near_resonance(d, roots, 3.0))
        rng = np.random.default_rng(seed)
        thp = th * (1 + 1e-3 * (rng.standard_normal(th.shape) + 1j * rng.standard_normal(th.shape)))
        err = {}
        for local in (False, True):
            Mi, _, Ki, _ = normal_mode_mck(lam, thp, fit_scale_factors(d, lam, thp, local=local))
            assert np.linalg.eigvalsh(Mi).min() > 0
            err[local] = (np.linalg.norm(Mi - M) / np.linalg.norm(M),
                          np.linalg.norm(Ki - K) / np.linalg.norm(K))
        assert err[True][0] < 5e-3 and err[True][1] < 5e-3, (seed, err)
        assert err[True][0] < err[False][0], (seed, err)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_mpc_criterion_spares_a_mode_whose_phase_no_line_sees(payload_10dof_300hz, seed):
    """Report noise model (2 % of each FRF's RMS magnitude, 2 degrees, uniform, 40 averages),
    seeds 1-3. The 1.29 Hz mode's nearest line is 0.29 Hz away, 11 half-widths (zeta f): the
    lines see only its skirts, so noise sets its estimated shape's phase and MPC (it failed
    criterion 3 on all three seeds before criterion 3 was limited to roots whose phase the
    lines see). It must be kept, and every root that criterion 3 would have rejected but
    that was kept must be a true mode (within 2 %), not noise."""
    frf, f_true = payload_10dof_300hz
    bands = overlapping_bands(1.0, 300.0, default_band_width_hz(frf.freq_hz), 0.5)
    res = process_bands(report_noise_frf(frf, seed=seed), bands)
    kept = res.freq_hz
    assert np.min(np.abs(kept - f_true[0])) < 0.02 * f_true[0], kept
    spared = [r for r in res.roots if r.mpc < 0.8 and not r.rejected]
    assert spared, "no root was kept past the MPC threshold: the case no longer tests the rule"
    for r in spared:
        assert np.min(np.abs(f_true - r.freq_hz)) < 0.02 * r.freq_hz, (r.freq_hz, r.mpc)


def test_damping_criteria_spare_a_mode_whose_damping_no_line_sees(payload_12dof_1158hz):
    """Report noise model, seed 2, 12 sensors, 1-1158 Hz (df = 2.26 Hz). The 1.29 Hz mode's
    estimates in bands 0 and 1 lie 0.0002 Hz apart, 11 half-widths from the nearest line,
    with damping -0.3 % and 1.9 %: criterion 2 and criterion 4's factor-2 damping check
    rejected the mode (the lines do not see its damping, sign included). It must be kept,
    with positive damping, and every root kept past criterion 2, and every mode selected
    through one, must be a true mode. (With two BLAS threads this record also had a noise
    root at 982 Hz pass criteria 1-4, with or without the rule: both its estimates are seen
    by the lines; it has the 992 Hz mode's shape and is rejected as such, see
    test_a_root_with_a_stronger_modes_shape_beside_it_is_rejected.)"""
    frf, f_true = payload_12dof_1158hz
    bands = overlapping_bands(1.0, 1158.0, default_band_width_hz(frf.freq_hz), 0.5)
    res = process_bands(report_noise_frf(frf, seed=2), bands)
    kept = res.freq_hz
    assert np.min(np.abs(kept - f_true[0])) < 0.02 * f_true[0], kept
    assert np.all(res.zeta > 0)
    spared = [r for r in res.roots if r.zeta < 0 and not r.rejected]
    assert spared and all(not r.damping_applied for r in spared)
    for r in spared:
        assert np.min(np.abs(f_true - r.freq_hz)) < 0.02 * r.freq_hz, (r.freq_hz, r.zeta)
    through = {r.cluster for r in spared}
    for r in res.selected:
        if r.cluster in through:
            assert np.min(np.abs(f_true - r.freq_hz)) < 0.01 * r.freq_hz, (r.freq_hz, r.zeta)


@pytest.mark.parametrize("seed", [3, 4])
def test_low_edge_band_keeps_the_suspension_modes_below_the_line_spacing(payload_12dof_1158hz,
                                                                         seed):
    """Report noise model, 12 sensors, 1-1158 Hz (df = 2.26 Hz): the suspension modes at
    1.29, 2.83 and 6.21 Hz lie in the part-band and the whole band at the record's low edge
    only, and no line resolves them. With those two bands alone, seed 3 lost the 1.29 Hz mode
    (band 0's estimate 1.775 Hz, MPC 0.07: nothing repeated band 1's 1.291 Hz) and seed 4
    took band 1's 1.533 Hz estimate (MPC 0.01) for it, paired with band 0's 1.292 Hz within
    df/8. Each of the three must be found within 2 %, nothing else below 10 Hz, and on seed 3
    the 1.29 Hz mode must be one that the low-edge band confirmed, not represents."""
    frf, f_true = payload_12dof_1158hz
    res = process_bands(report_noise_frf(frf, seed=seed),
                        overlapping_bands(1.0, 1158.0, default_band_width_hz(frf.freq_hz), 0.5))
    low = res.low_edge_band
    assert low is not None and res.bands_hz[low] == pytest.approx((1.0, 1.0 + 1.5 * (1157.0 / 12)))
    below = res.freq_hz[res.freq_hz < 10.0]
    assert below.size == 3 and np.allclose(below, f_true[:3], rtol=0.02), below
    assert not any(r.low_edge for r in res.selected)
    if seed == 3:
        first = res.selected[0]
        members = [r for r in res.roots if r.cluster == first.cluster and not r.rejected]
        assert sorted(r.band for r in members) == [1, low]


@pytest.mark.parametrize("seed, noise_hz", [(10, 321.9), (19, 322.4)])
def test_no_second_mode_inside_a_resolved_modes_half_power_band(payload_12dof_1158hz, seed,
                                                                noise_hz):
    """Report noise model, 12 sensors, 1-1158 Hz: a root 3.3 Hz (seed 10) or 3.8 Hz (seed 19)
    above the 318.57 Hz mode, damping below 0.2 %, repeated in bands 6 and 7, was selected as
    a second mode (see
    test_unresolved_mode_inside_a_resolved_modes_half_power_band_is_rejected). Exactly one
    mode must be selected within 2 % of the 318.57 Hz mode, within 0.1 % of it, and the roots
    near the noise root's frequency must all be rejected."""
    frf, f_true = payload_12dof_1158hz
    res = process_bands(report_noise_frf(frf, seed=seed),
                        overlapping_bands(1.0, 1158.0, default_band_width_hz(frf.freq_hz), 0.5))
    mode = f_true[np.argmin(np.abs(f_true - 318.6))]
    near = res.freq_hz[np.abs(res.freq_hz - mode) < 0.02 * mode]
    assert near.size == 1 and abs(near[0] - mode) < 1e-3 * mode, near
    noise = [r for r in res.roots if abs(r.freq_hz - noise_hz) < 0.1]
    assert noise and all(r.rejected for r in noise), [(r.freq_hz, r.rejected) for r in noise]


def test_resonance_cut_by_an_edge_inside_the_layout_only():
    """The payload's 585.47 Hz mode (zeta 2 %, half-power half-width 11.7 Hz) in the bands
    of 12 sensors at 1-1158 Hz: 6 Hz above the lower edge of band 13 (579.5-675.9 Hz), cut;
    in band 12 (531.3-627.7 Hz), centred, not cut. An edge at the layout's own end cuts
    every band alike and does not count."""
    layout = (1.0, 1158.0)
    assert resonance_cut_by_band_edge(585.47, 0.02, (579.5, 675.9), layout)
    assert resonance_cut_by_band_edge(585.47, -0.02, (579.5, 675.9), layout)  # |zeta|
    assert not resonance_cut_by_band_edge(585.47, 0.02, (531.3, 627.7), layout)
    assert not resonance_cut_by_band_edge(585.47, 0.002, (579.5, 675.9), layout)  # narrower
    assert resonance_cut_by_band_edge(1150.0, 0.02, (1061.6, 1155.0), layout)
    assert not resonance_cut_by_band_edge(1150.0, 0.02, (1061.6, 1158.0), layout)
    assert not resonance_cut_by_band_edge(1.29, 0.02, (1.0, 97.4), layout)


def test_a_mode_whose_every_estimate_an_edge_cuts_must_pass_criterion_3_elsewhere():
    """Roots as band processing found them on the payload (12 sensors, 1-1158 Hz, the
    report's noise, seed 19): the 585.47 Hz mode at 585.406 Hz, MPC 0.98, in band 12, which
    holds its whole resonance, and at 584.941 Hz, MPC 0.61, in band 13, whose lower edge
    (579.5 Hz) cuts it. Criterion 3 spared band 13's estimate: the two are one mode,
    represented by band 12's. Two estimates about 1 Hz either side of 579.5 Hz, the edge of
    bands 11 and 13 (made up), each spared for that reason, with no estimate from band 12
    that passed criterion 3, are rejected as "low MPC". So is a computational root of seed
    10, 978.58 Hz with 4.2 % damping and MPC 0.48 in band 20, cut by its upper edge; band
    21's 986.01 Hz (4.3 %, MPC 0.83) passed criterion 3 but is cut too, so it confirms
    nothing and, alone, is not repeated."""
    lines = np.linspace(1.0, 1158.0, 512)
    bands = overlapping_bands(1.0, 1158.0, default_band_width_hz(lines), 0.5)
    assert bands[13][0] == pytest.approx(579.5, abs=0.1) == bands[11][1]
    roots = [_root(12, 585.40640, 0.0204), _root(13, 584.94091, 0.0213),
             _root(11, 578.6, 0.02), _root(13, 580.4, 0.02),
             _root(20, 978.58041, 0.0416), _root(21, 986.00946, 0.0425)]
    for r, mpc in zip(roots, [0.98, 0.61, 0.7, 0.7, 0.48, 0.83]):
        r.mpc = mpc
        r.edge_cut = resonance_cut_by_band_edge(r.freq_hz, r.zeta, bands[r.band], (1.0, 1158.0))
        r.mpc_applied = not (r.edge_cut and mpc < 0.8)
    assert [r.edge_cut for r in roots] == [False, True, True, True, True, True]
    cluster_repeated(roots, 0.125, lines)
    assert [r.cluster == roots[k - k % 2].cluster >= 0 for k, r in enumerate(roots)] == [True] * 6
    reject_edge_cut_only(roots)
    assert [r.rejected for r in roots] == ["", "", "low MPC", "low MPC", "low MPC", "not repeated"]
    assert [r.freq_hz for r in pick_representatives(roots, bands)] == [585.40640]
    # A spared estimate confirms, never represents, even where a wider damping estimate puts
    # it farther from its band's edge than the whole band's estimate is from its own.
    bands = [(0.0, 101.2), (98.4, 200.0)]
    pair = [_root(0, 100.0, 0.01), _root(1, 100.01, 0.02)]
    for r in pair:
        r.edge_cut = resonance_cut_by_band_edge(r.freq_hz, r.zeta, bands[r.band], (0.0, 200.0))
    assert [r.edge_cut for r in pair] == [False, True]
    pair[1].mpc, pair[1].mpc_applied = 0.5, False
    cluster_repeated(pair, 0.125, np.linspace(0.0, 200.0, 401))
    reject_edge_cut_only(pair)
    assert not any(r.rejected for r in pair)
    assert pick_representatives(pair, bands) == [pair[0]]


def test_a_mode_cut_by_a_band_edge_is_found_by_the_band_centred_on_it(payload_12dof_1158hz):
    """Report noise model, seed 19, 12 sensors, 1-1158 Hz: the rotation-dominated 585.47 Hz
    mode failed criterion 3 (MPC 0.61) in band 13, whose lower edge cuts its resonance, and
    was lost, though band 12 found it with MPC 0.98 (see
    test_a_mode_whose_every_estimate_an_edge_cuts_must_pass_criterion_3_elsewhere). It must
    be found within 0.5 %, represented by a root whose MPC passed criterion 3."""
    frf, f_true = payload_12dof_1158hz
    res = process_bands(report_noise_frf(frf, seed=19),
                        overlapping_bands(1.0, 1158.0, default_band_width_hz(frf.freq_hz), 0.5))
    mode = f_true[np.argmin(np.abs(f_true - 585.5))]
    k = int(np.argmin(np.abs(res.freq_hz - mode)))
    assert abs(res.freq_hz[k] - mode) < 5e-3 * mode, res.freq_hz
    assert res.selected[k].mpc >= 0.8 and res.selected[k].mpc_applied


@pytest.mark.parametrize("seed, echo_hz, mode_hz, verdict", [
    (1, 81.8, 78.87, "same shape as a stronger mode"),
    (3, 116.0, 117.55, "inside a resolved mode's half-power band")])
def test_a_root_with_a_stronger_modes_shape_beside_it_is_rejected(payload_10dof_300hz, tmp_path,
                                                                   seed, echo_hz, mode_hz, verdict):
    """Report noise model, 10 sensors, 1-300 Hz. On seeds 1 and 3 a root fitted to the noise
    on a mode's skirt (81.8 Hz beside 78.9 Hz; 116.0 Hz beside 117.5 Hz) came out in the two
    bands that share those lines and passed the four criteria as an eighth mode. Its shape is
    the mode's at the sensors (MAC 0.91-0.97) and it holds a small share of the FRF: it must
    be rejected, and exactly the seven true modes kept, each within 1 %. Seed 3's root (damping
    0.19 %, half-power bandwidth 0.46 Hz, under the 0.59 Hz line spacing) lies 1.5 Hz below
    the 117.55 Hz mode, inside its half-power band (+-2.35 Hz), and is rejected for that before
    its shape is compared; seed 1's (damping 1.1-1.2 %, resolved) lies 2.9 Hz above the 78.87
    Hz mode, outside its half-power band (+-1.58 Hz), and is rejected for its shape."""
    frf, f_true = payload_10dof_300hz
    bands = overlapping_bands(1.0, 300.0, default_band_width_hz(frf.freq_hz), 0.5)
    res = process_bands(report_noise_frf(frf, seed=seed), bands)
    assert res.freq_hz.size == f_true.size
    assert np.max(np.abs(res.freq_hz - f_true) / f_true) < 0.01, res.freq_hz
    echoes = [r for r in res.roots if r.rejected == verdict]
    assert echoes and all(abs(r.freq_hz - echo_hz) < 0.1 for r in echoes), [r.freq_hz for r in echoes]
    kept = res.selected[int(np.argmin(np.abs(res.freq_hz - mode_hz)))]
    d = res.data[kept.band]
    lo, hi = bands[kept.band]
    band_roots = [r for r in res.roots if r.band == kept.band and lo <= r.freq_hz <= hi and r.zeta > 0]
    share = frf_share(d, band_roots)
    assert share[next(k for k, r in enumerate(band_roots) if r is kept)] > 0.9
    plot_band_roots(str(tmp_path / "roots.png"), res, f_true)  # the chart knows the verdict


# Unevenly spaced lines: a stepped-sine sweep on a logarithmic grid


def test_default_bands_hold_equal_line_counts_on_an_uneven_grid():
    """Evenly spaced lines keep the bands of one width in Hz; a log grid gets bands of equal
    line count, every line in two bands and each end's part-band holding half a band."""
    even = np.linspace(1.0, 300.0, 512)
    assert default_bands(even) == overlapping_bands(1.0, 300.0, default_band_width_hz(even), 0.5)
    f = 20.0 * np.geomspace(1.0, 75.0, 152)  # 20-1500 Hz, 2.9 % apart
    bands = default_bands(f)
    assert bands[0][0] == f[0] and bands[-1][1] == f[-1]
    held = np.array([np.count_nonzero((f >= lo) & (f <= hi)) for lo, hi in bands])
    cover = sum(((f >= lo) & (f <= hi)).astype(int) for lo, hi in bands)
    assert cover.min() == 2
    assert held[1:-1].min() >= 24 and held[1:-1].max() - held[1:-1].min() <= 2
    assert min(held[0], held[-1]) >= 12
    # One input and 16 sensors need 18 lines a band: the part-bands are widened to hold them.
    need = band_min_lines(16, 1)
    assert need == 18
    assert min(np.count_nonzero((f >= lo) & (f <= hi)) for lo, hi in default_bands(f, 0.5, need)) >= need


def test_line_spacing_at_is_the_spacing_of_the_bracketing_lines():
    f = np.array([10.0, 11.0, 13.0, 17.0])
    assert line_spacing_at(f, [9.0, 10.5, 12.0, 13.0, 16.0, 20.0]).tolist() == [1, 1, 2, 2, 4, 4]


def test_default_bands_find_every_mode_of_a_log_sweep(log_sweep_record):
    """Bands of one width in Hz (the even-grid rule, 1/12 of the span) hold fewer lines above
    450 Hz than step 1 needs with 16 sensors and 2 inputs (10), so no band there is processed
    and the modes at 567, 828 and 1320 Hz are lost. Bands of equal line count find every
    mode."""
    frf, fn = log_sweep_record
    f = frf.freq_hz
    assert fn.size == 9 and fn[-1] > 1300
    by_hz = process_bands(frf, overlapping_bands(f[0], f[-1], (f[-1] - f[0]) / 12, 0.5), solver="ls")
    lost = [x for x in fn if not np.any(np.abs(by_hz.freq_hz - x) < 0.01 * x)]
    assert len(lost) == 3 and min(lost) > 450
    res = process_bands(frf, default_bands(f, 0.5, band_min_lines(16, 2)), solver="ls")
    assert res.freq_hz.size == fn.size
    assert np.allclose(res.freq_hz, fn, rtol=1e-3)  # damped vs undamped: 2 % damping, 2e-4

