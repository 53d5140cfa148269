"""The band-processed modal model (``ssid.modal_model.identify_mck_modal``).

Each case builds a system with known M, C, K, synthesises its accelerances and checks what
comes back against it.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_identify import _four_dof_with_unmeasured_modes, true_frequencies_hz

from ssid.band_select import identify_mck_band_select
from ssid.correlate import modal_assurance
from ssid.errors import IdentificationError
from ssid.frf import FRFData, accelerance_from_model
from ssid.modal import real_modes
from ssid.modal_model import identify_mck_modal
from ssid.models import example_system
from ssid.models.payload import modal_damping
from ssid.noise import report_noise_frf


def _six_dof_modally_damped(f_hz: np.ndarray):
    """example_system(6) (modes 15.6-410.8 Hz) with 2 % modal damping: its modes are real
    normal modes, the form the modal model assembles, so M, C, K are recoverable exactly."""
    M, _, K, dofs = example_system(6, seed=1)
    C = modal_damping(M, K, 0.02)
    return (M, C, K), accelerance_from_model(M, C, K, dofs, f_hz, dofs, [dofs[0], dofs[3]])


def test_modal_model_recovers_a_modally_damped_system_exactly():
    """All six modes in 5-700 Hz (1024 lines): band processing finds each, BP3 scales them and
    the normal-mode assembly gives back M, C, K. Measured 1.3e-13 (M), 1.4e-12 (C),
    2.0e-13 (K) in Frobenius norm; the bound 1e-9 is rounding plus the ill-conditioning of the
    narrow bands' step 1, far below any modelling error."""
    (M, C, K), frf = _six_dof_modally_damped(np.linspace(5.0, 700.0, 1024))
    r = identify_mck_modal(frf)
    for A, B in ((r.M, M), (r.C, C), (r.K, K)):
        assert np.linalg.norm(A - B) / np.linalg.norm(B) < 1e-9
    f_true, zeta_true = true_frequencies_hz(M, C, K)
    np.testing.assert_allclose(r.natural_freq_hz, f_true, rtol=1e-9)
    np.testing.assert_allclose(r.damping_ratio, zeta_true, rtol=1e-7)
    assert r.solver == "bands" and not r.warnings


@pytest.mark.parametrize("seed", [1, 2])
def test_modal_model_under_the_reports_noise(seed):
    """The same system under the report's noise model (``report_noise_frf``: uniform 2 %
    magnitude and 2 degree phase errors of each FRF's RMS level on responses and forces, 40
    averages; fixed seeds). Over seeds 1-6 the frequencies came within 4.7e-5, the damping
    ratios within 0.25 % and M, K within 0.34 % (Frobenius); the bounds (1e-4, 1 %, 1 %) leave
    room for the seed-to-seed spread, not for a wrong mode or a lost one."""
    (M, C, K), frf = _six_dof_modally_damped(np.linspace(5.0, 700.0, 1024))
    r = identify_mck_modal(report_noise_frf(frf, seed=seed))
    f_true, zeta_true = true_frequencies_hz(M, C, K)
    np.testing.assert_allclose(r.natural_freq_hz, f_true, rtol=1e-4)
    np.testing.assert_allclose(r.damping_ratio, zeta_true, rtol=1e-2)
    for A, B in ((r.M, M), (r.K, K)):
        assert np.linalg.norm(A - B) / np.linalg.norm(B) < 1e-2


def test_modal_model_refuses_a_band_with_fewer_modes_than_dofs():
    """20-150 Hz holds 3 of the 6 modes: no 6-DOF modal model exists (M^-1 would be
    singular), which must be said, not papered over."""
    _, frf = _six_dof_modally_damped(np.linspace(20.0, 150.0, 512))
    with pytest.raises(IdentificationError, match="3 modes .* 6 are needed"):
        identify_mck_modal(frf)


@pytest.mark.parametrize("seed", [1, 3])
def test_modal_model_holds_true_modes_when_the_band_holds_more_modes_than_dofs(seed):
    """4 sensors, 7 modes in 1-2000 Hz (the 4-DOF system's own, non-proportionally damped,
    and 3 of unmeasured structure at 800, 1100, 1500 Hz). The modal model holds the 4-DOF
    system's modes, the strongest at these sensors, to 0.1 %: not exact, because each narrow
    band's 4-DOF step-1 model absorbs the modes outside the band, which shifts its roots
    (measured 5.9e-4 at 347 Hz, below the unmeasured 800 Hz mode, seed 1; 4e-5 for seed 3).
    M and K are positive definite; the band search scores the modal candidate with the others
    on the output error over all lines and keeps a physical model."""
    (M, C, K), frf = _four_dof_with_unmeasured_modes(seed)
    f_sys, _ = true_frequencies_hz(M, C, K)
    r = identify_mck_modal(frf)
    np.testing.assert_allclose(r.natural_freq_hz, f_sys, rtol=1e-3)
    np.testing.assert_allclose(r.undamped_freq_hz, r.natural_freq_hz, rtol=1e-9)
    assert np.linalg.eigvalsh(r.M).min() > 0 and np.linalg.eigvalsh(r.K).min() > 0
    cands: dict = {}
    sel = identify_mck_band_select(frf, candidates=cands)
    assert (float(frf.freq_hz[-1]), "bands") in cands
    assert np.linalg.eigvalsh(sel.M).min() > 0


def test_modal_model_keeps_the_analysts_target_modes_first():
    """Five modes at three sensors (a modal sum: real shapes, 2 % damping), the two upper
    ones the strongest (modal masses 10 times smaller). Left to the data, a 3-DOF modal model
    holds those two; given the three lower modes' shapes (an FE model's targets, with
    frequencies 2 % off as an FE model's would be), it holds those three, to 0.1 % (the band
    roots' bias from modes outside each band, as above)."""
    rng = np.random.default_rng(7)
    f_r = np.array([50.0, 120.0, 300.0, 500.0, 800.0])
    m_r = np.array([1.0, 1.0, 1.0, 0.1, 0.1])
    phi = rng.standard_normal((3, 5))
    f = np.linspace(10.0, 1000.0, 512)
    w, wr = 2 * np.pi * f, 2 * np.pi * f_r
    h = -(w**2)[:, None] / ((wr**2)[None] - (w**2)[:, None] + 2j * 0.02 * wr[None] * w[:, None])
    H = np.einsum("kr,ir,jr->kij", h / m_r, phi, phi[[0, 2]])
    dofs = ["1+Z", "2+Z", "3+Z"]
    frf = FRFData(freq_hz=f, H=H, outputs=dofs, inputs=[dofs[0], dofs[2]])
    auto = identify_mck_modal(frf)
    assert np.sum(np.min(np.abs(auto.natural_freq_hz[:, None] / f_r[3:] - 1), axis=1) < 1e-3) == 2
    chosen = identify_mck_modal(frf, prefer_shapes=phi[:, :3], prefer_freq_hz=f_r[:3] * 1.02)
    np.testing.assert_allclose(chosen.natural_freq_hz, f_r[:3], rtol=1e-3)
    assert np.linalg.eigvalsh(chosen.M).min() > 0


def test_a_model_one_mode_short_gets_the_mode_above_the_band_as_its_residual_pair():
    """5-350 Hz holds 5 of the 6 modes; the 6th (410.8 Hz, 1.17 times the edge) is in the
    data as its resonance's lower skirt, all that the found modes leave. With uniform 2 %
    modal damping the pair's assumed damping (the found modes' median) is the true one, so
    the pair must land on that mode, and M, C, K come back whole. Measured: 4.2e-9 in the
    pair's frequency, 1.0e-4 (M), 1.2e-4 (C), 8.0e-5 (K) in Frobenius norm. Not exact as
    with every mode in the band: BP3 scales the found modes with residual terms standing in
    for the 6th, which leaves their modal masses about 1e-4 off. That error stays out of the
    pair (the found modes' residues are fitted alongside it; 5.5e-7 in its frequency and
    1.7e-4 in M when they were not), but is in the found modes. The bounds (1e-5, 1e-3) are
    that with room; a pair on another mode or an effective pole would be percents off. Without the pair
    (``residual_pair=False``) the band gives no 6-DOF modal model."""
    (M, C, K), frf = _six_dof_modally_damped(np.linspace(5.0, 350.0, 1024))
    r = identify_mck_modal(frf)
    f_true, zeta_true = true_frequencies_hz(M, C, K)
    assert r.info["bands"]["residual_pair_hz"] == pytest.approx(f_true[-1], rel=1e-5)
    np.testing.assert_allclose(r.natural_freq_hz, f_true, rtol=1e-5)
    for A, B in ((r.M, M), (r.C, C), (r.K, K)):
        assert np.linalg.norm(A - B) / np.linalg.norm(B) < 1e-3
    assert any("residual" in w and "stands for them" in w for w in r.warnings)
    assert r.n_rigid_body_modes == 0
    # Grounded: what the found modes leave below them is no mass line.
    with pytest.raises(IdentificationError, match="5 modes .* 6 are needed.*do not show rigid-body"):
        identify_mck_modal(frf, residual_pair=False)


def test_a_residual_pair_takes_the_found_modes_damping_and_the_nearest_mode_above():
    """The same band with the 6th mode at 5 % damping and the others at 2 %: the pair's
    damping ratio (2 %, the found modes' median) is an assumption the band cannot check,
    so the frequency it fits to the skirt moves. Measured: 2.5 % below the 410.8 Hz mode
    (a less damped pole must sit lower to give the same skirt), shape MAC 1 to rounding; the
    found modes stay exact (1e-14). The bounds (3 %, MAC 0.999) allow for that bias, not for
    another mode (the nearest is 250.5 Hz, inside the band); the band search does not
    prefer such a model for being band-processed (here it keeps an ``stls`` fit)."""
    M, _, K, dofs = example_system(6, seed=1)
    C = modal_damping(M, K, np.array([0.02] * 5 + [0.05]))
    f = np.linspace(5.0, 350.0, 1024)
    frf = accelerance_from_model(M, C, K, dofs, f, dofs, [dofs[0], dofs[3]])
    r = identify_mck_modal(frf)
    f_true, zeta_true = true_frequencies_hz(M, C, K)
    np.testing.assert_allclose(r.natural_freq_hz[:5], f_true[:5], rtol=1e-9)
    assert r.natural_freq_hz[5] == pytest.approx(f_true[5], rel=3e-2)
    assert r.damping_ratio[5] == pytest.approx(0.02, rel=1e-9)
    wu, phi_true = real_modes(M, K)
    assert modal_assurance(r.mode_shapes[:, 5:], phi_true[:, 5:])[0, 0] > 0.999
    assert np.linalg.eigvalsh(r.M).min() > 0
    sel = identify_mck_band_select(frf)
    assert "band-processed" not in sel.info["band_select"]["choice"]


def _free_beam(f_hi_hz: float = 6000.0):
    """A free-free beam (3 cubic elements, Z and RY at its 4 nodes, 2 % modal damping): two
    rigid-body modes and 6 elastic ones (190-4923 Hz), every DOF measured, inputs at both
    ends; 1200 lines 20 Hz-``f_hi_hz``, the rigid-body modes below the first."""
    from test_rigid_body import free_beam

    M, C, K, dofs = free_beam()
    return (M, C, K), accelerance_from_model(M, C, K, dofs, np.linspace(20, f_hi_hz, 1200), dofs,
                                             ["0+Z", "3+Z"])


@pytest.mark.parametrize("seed", [None, 1])
def test_a_free_free_model_gets_its_rigid_body_modes_from_the_mass_line(seed):
    """Band processing finds the 6 elastic modes, not the two rigid-body modes at 0 Hz: the
    8-DOF modal model takes them from the mass line of what the found modes leave (a free
    structure's accelerance below its first mode), and is the beam's. Noise-free, measured
    M 3.2e-10, K 1.2e-11, C 1.2e-7 (relative Frobenius), elastic frequencies 3.2e-14: the
    bounds 1e-8 and 1e-5 are rounding and band processing's accuracy on exact data with
    room. Under the report's noise (seed 1) M 0.63 %, K 2.5 %, C 0.78 %, frequencies 5.9e-5
    (the whole-band default on the same record: M 0.35 %, K 1.2 %): bounds 2 %, 5 %, 2 %,
    1e-3. Without rigid-body modes (``rigid_body=False``) no 8-DOF modal model exists."""
    (M, C, K), frf = _free_beam()
    data = frf if seed is None else report_noise_frf(frf, seed=seed)
    r = identify_mck_modal(data)
    assert r.n_rigid_body_modes == 2 and r.info["bands"]["n_rigid_body_modes"] == 2
    assert any("2 rigid-body mode(s) (free-free structure)" in w for w in r.warnings)
    rel = [np.linalg.norm(A - B) / np.linalg.norm(B) for A, B in ((r.M, M), (r.K, K), (r.C, C))]
    f_true = real_modes(M, K)[0][2:] / (2 * np.pi)
    assert np.all(r.undamped_freq_hz[:2] == 0.0)
    if seed is None:
        assert rel[0] < 1e-8 and rel[1] < 1e-8 and rel[2] < 1e-5
        np.testing.assert_allclose(r.undamped_freq_hz[2:], f_true, rtol=1e-10)
    else:
        assert rel[0] < 0.02 and rel[1] < 0.05 and rel[2] < 0.02
        np.testing.assert_allclose(r.undamped_freq_hz[2:], f_true, rtol=1e-3)
    assert not any("not positive" in w for w in r.warnings)
    with pytest.raises(IdentificationError, match="6 modes .* 8 are needed"):
        identify_mck_modal(data, rigid_body=False)



@pytest.mark.parametrize("seed", [None, 1])
def test_a_free_free_model_short_of_the_mode_above_gets_rigid_body_modes_and_a_pair(seed):
    """The free beam measured 20-4500 Hz: the bands find 5 elastic modes, and the 8-DOF
    model lacks the two rigid-body modes below the band and the 4923 Hz mode above it (1.09
    times the edge). Both are in what the found modes leave of the FRFs, the mass line and
    that mode's skirt, and are fitted together. With uniform 2 % damping the pair's assumed
    damping is the true one, so the pair must land on that mode. Noise-free, measured: pair
    frequency 2.5e-8, found ones 1.5e-13, M 6.9e-6, K 3.2e-4, C 7.6e-5 (relative Frobenius;
    K and C carry BP3's scale-factor error of the found modes, 3.7e-4 in the 4002 Hz mode's
    shape, as in the grounded case above): bounds 1e-6, 1e-10, 1e-3. Under the report's
    noise, seeds 1-3 gave M 0.28-0.74 %, K 1.1-1.7 %, C 0.36-0.81 %, frequencies within
    8.6e-5: the bounds (seed 1) are those of the whole-band free beam above. Without either
    completion the model is refused with the other's reason: 3 rigid-body modes from 2
    inputs, or a pair for 3 modes short (checked noise-free)."""
    (M, C, K), frf = _free_beam(4500.0)
    data = frf if seed is None else report_noise_frf(frf, seed=seed)
    r = identify_mck_modal(data)
    f_true = real_modes(M, K)[0][2:] / (2 * np.pi)
    assert r.n_rigid_body_modes == 2
    assert any("2 rigid-body mode(s)" in w for w in r.warnings)
    assert any("last pair" in w and "stands for them" in w for w in r.warnings)
    rel = [np.linalg.norm(A - B) / np.linalg.norm(B) for A, B in ((r.M, M), (r.K, K), (r.C, C))]
    assert np.all(r.undamped_freq_hz[:2] == 0.0)
    if seed is None:
        assert r.info["bands"]["residual_pair_hz"] == pytest.approx(f_true[-1], rel=1e-6)
        np.testing.assert_allclose(r.undamped_freq_hz[2:7], f_true[:5], rtol=1e-10)
        assert max(rel) < 1e-3
    else:
        np.testing.assert_allclose(r.undamped_freq_hz[2:], f_true, rtol=1e-3)
        assert rel[0] < 0.02 and rel[1] < 0.05 and rel[2] < 0.02
        return
    with pytest.raises(IdentificationError, match="3 rigid-body modes need at least as many inputs"):
        identify_mck_modal(data, residual_pair=False)
    with pytest.raises(IdentificationError, match="a residual pair alone completes a model one mode short, not 3"):
        identify_mck_modal(data, rigid_body=False)
