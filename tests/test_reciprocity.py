"""Reciprocity check (ssid.reciprocity) on FRFs synthesised from a known M, C, K: the 14-DOF
example chain (symmetric matrices, so its FRF matrix is exactly symmetric) driven at three
DOFs, with the faults a MIMO test meets put in by hand: a force gauge's calibration off, an
accelerometer mounted upside down, one FRF measured on a stiffer structure (a non-linear
joint at another level)."""

from __future__ import annotations

import numpy as np
import pytest

from ssid.frf import FRFData, accelerance_from_model
from ssid.models import example_system
from ssid.reciprocity import CALIBRATION_TOLERANCE, reciprocity_check

INPUTS = ["2", "7", "12"]


def _chain(n_freq: int = 400) -> FRFData:
    M, C, K, dofs = example_system(14, seed=1)
    labels = [str(k) for k in range(len(dofs))]
    return accelerance_from_model(M, C, K, labels, np.linspace(2.0, 400.0, n_freq), labels, INPUTS)


def _noisy(frf: FRFData, rel: float, seed: int) -> FRFData:
    """Noise model: each value gets independent circular complex Gaussian noise of standard
    deviation ``rel`` times its own magnitude (plus a floor of 1e-6 of the largest), and
    ``H_var`` states that variance."""
    rng = np.random.default_rng(seed)
    var = (rel * np.abs(frf.H)) ** 2 + (1e-6 * np.max(np.abs(frf.H))) ** 2
    e = rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape)
    return FRFData(frf.freq_hz, frf.H + np.sqrt(var / 2) * e, frf.outputs, frf.inputs, H_var=var)


def _by_pair(frf: FRFData) -> dict:
    return {(p.dof_a, p.dof_b): p for p in reciprocity_check(frf)}


def test_a_symmetric_structure_is_reciprocal_at_every_pair():
    pairs = _by_pair(_chain())
    assert set(pairs) == {("2", "7"), ("2", "12"), ("7", "12")}
    for p in pairs.values():
        assert p.reciprocal and p.curves.n_lines == 400
        assert abs(p.curves.gain - 1) < 1e-10 and p.curves.frac == pytest.approx(1.0, abs=1e-12)
        assert np.isnan(p.curves.gain_std) and np.isnan(p.curves.residual_ratio)  # no variances stated
    assert reciprocity_check(FRFData(np.array([1.0]), np.ones((1, 1, 1)), ["a"], ["a"])) == []
    dead = _chain()
    dead.H[:, :, 2] = 0.0  # a column that reads nothing (a channel dead in the data)
    pairs = _by_pair(dead)
    assert not pairs[("2", "12")].reciprocal and "a dead channel?" in pairs[("2", "12")].describe()
    assert pairs[("2", "7")].reciprocal


def test_a_force_gauge_off_by_5_percent_shows_as_the_gain_of_its_pairs():
    """Force gauge at input 7 reads 1.05 times the force: every FRF of that input is 1/1.05
    of the truth. H(2,7) / H(7,2) = 1/1.05, H(7,12) / H(12,7) = 1.05; the pair without it
    stays reciprocal."""
    frf = _chain()
    frf.H[:, :, 1] /= 1.05
    pairs = _by_pair(frf)
    assert pairs[("2", "7")].curves.gain == pytest.approx(1 / 1.05, abs=1e-10)
    assert pairs[("7", "12")].curves.gain == pytest.approx(1.05, abs=1e-10)
    assert not pairs[("2", "7")].reciprocal and not pairs[("7", "12")].reciprocal
    assert pairs[("2", "12")].reciprocal
    assert "calibration" in pairs[("7", "12")].describe() and "NOT RECIPROCAL" in pairs[("7", "12")].describe()
    # Within what calibrations hold, the same fault is no finding.
    frf = _chain()
    frf.H[:, :, 1] /= 1 + CALIBRATION_TOLERANCE / 2
    assert all(p.reciprocal for p in reciprocity_check(frf))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_under_noise_reciprocal_data_pass_and_faults_are_found(seed):
    """1 % noise on every value (stated in H_var). Reciprocal data: the residual is the noise
    (ratio about 1: the mean of 400 unit exponentials lies within 1 +- 0.2 with overwhelming
    probability) and the gain within 3 of its standard deviations of 1. An accelerometer
    upside down at input 12 is a gain of -1; a 1.5 % calibration error, inside the tolerance
    but 15 or more standard deviations out, is not a finding."""
    clean = _noisy(_chain(), 0.01, seed)
    for p in reciprocity_check(clean):
        assert p.reciprocal, p.describe()
        assert 0.8 < p.curves.residual_ratio < 1.2 and abs(p.curves.gain - 1) < 3 * p.curves.gain_std
        assert 0 < p.curves.gain_std < 2e-3
    frf = _chain()
    frf.H[:, frf.outputs.index("12"), :] *= -1
    flipped = _by_pair(_noisy(frf, 0.01, seed))
    assert flipped[("2", "12")].curves.gain.real == pytest.approx(-1, abs=0.01)
    assert "opposite sign" in flipped[("2", "12")].describe() and flipped[("2", "7")].reciprocal
    frf = _chain()
    frf.H[:, :, 1] /= 1.015
    assert all(p.reciprocal for p in reciprocity_check(_noisy(frf, 0.01, seed)))


def test_a_shape_difference_beyond_the_noise_is_found():
    """H(2,12) measured on a structure 3 % stiffer (a joint at another level): no gain
    explains it, so the residual is far beyond the stated noise; FRAC drops below 1."""
    M, C, K, dofs = example_system(14, seed=1)
    labels = [str(k) for k in range(len(dofs))]
    f = np.linspace(2.0, 400.0, 400)
    frf = _noisy(accelerance_from_model(M, C, K, labels, f, labels, INPUTS), 0.01, 5)
    stiff = accelerance_from_model(M, C, 1.03 * K, labels, f, labels, INPUTS)
    frf.H[:, frf.outputs.index("2"), 2] = stiff.H[:, stiff.outputs.index("2"), 2]
    p = _by_pair(frf)[("2", "12")]
    assert not p.reciprocal and p.curves.residual_ratio > 100 and p.curves.frac < 0.9
    assert "shapes differ" in p.describe()


def test_identify_warns_when_its_data_are_not_reciprocal():
    """SSID fits symmetric M, C, K: on data whose force gauge at 7 is 5 % off, the result
    carries a warning naming the pairs and the gain; on the same data calibrated, none."""
    from ssid.identify import identify_mck

    frf = _chain(200)
    assert not any("reciprocity" in w for w in identify_mck(frf, solver="ls").warnings)
    frf.H[:, :, 1] /= 1.05
    said = [w for w in identify_mck(frf, solver="ls").warnings if w.startswith("reciprocity")]
    assert len(said) == 2 and all("NOT RECIPROCAL" in w and "check these transducers" in w for w in said), said
    assert said[0].startswith("reciprocity 2 <-> 7: gain 0.9524")


def _uncoupled_xz() -> FRFData:
    """Two masses moving in X and in Z, directions that do not couple (block-diagonal M, C, K:
    X springs 1e4 N/m, Z 1.7e4 N/m, unit masses, C = 1e-3 K + 0.2 M), driven at 1+X and 1+Z.
    H(1+X, 1+Z) and H(1+Z, 1+X) are exactly zero at every line, the drive points respond."""
    K1 = np.array([[2.0, -1.0], [-1.0, 1.0]])
    M, K = np.eye(4), np.zeros((4, 4))
    K[:2, :2], K[2:, 2:] = 1e4 * K1, 1.7e4 * K1
    labels = ["1+X", "2+X", "1+Z", "2+Z"]
    return accelerance_from_model(M, 1e-3 * K + 0.2 * M, K, labels, np.linspace(1.0, 60.0, 400), labels,
                                  ["1+X", "1+Z"])


def test_two_cross_frfs_that_are_both_zero_are_reciprocal():
    """Uncoupled directions: both cross FRFs zero is the same curve both ways, reciprocal. It
    was "NOT RECIPROCAL ... zero at all 400 lines (a dead channel?)", and ssidlab identify
    warned to check the transducers of a perfect record (QA). A dead channel is zero in its
    drive point as well: then the line still says so, as a question."""
    from ssid.identify import identify_mck

    frf = _uncoupled_xz()
    assert not np.any(frf.H[:, 0, 1]) and not np.any(frf.H[:, 2, 0])
    (p,) = reciprocity_check(frf)
    assert p.reciprocal and p.curves.both_zero and not p.curves.dead and p.silent_drive_points == ()
    assert p.describe() == ("reciprocity 1+X <-> 1+Z: H(1+X,1+Z) and H(1+Z,1+X) are both zero at all 400 "
                            "lines: reciprocal (the two drive points do not couple)")
    assert p.curves.to_json_dict()["agree"] and p.curves.to_json_dict()["both_zero"]
    assert not any("reciprocity" in w for w in identify_mck(frf, solver="ls").warnings)
    frf.H[:, 2, :] = 0.0  # the accelerometer at 1+Z measured nothing: its drive point is zero too
    (p,) = reciprocity_check(frf)
    assert p.reciprocal and p.silent_drive_points == ("1+Z",)
    assert p.describe().endswith(": reciprocal; the drive point H(1+Z,1+Z) is zero too (a dead channel?)")


@pytest.mark.parametrize("stated", [False, True])
def test_cross_frfs_at_their_noise_level_are_not_testable_not_a_fault(stated):
    """Two chains in X and Z that nothing couples, driven at 1+X and 1+Z; every value gets
    circular complex Gaussian noise of 1e-3 of the largest |H| (seed 3), stated as H_var or
    not. The cross FRFs are that noise alone: their gain (0.017) and FRAC (0.0003) read as a
    calibration fault at these points (a QA pass). They are now said to be at their noise
    level, not testable, and no fault. The same noise on a pair that couples, with its force
    gauge 5 % off, on a grid of 12 lines (a roughness as large as the curves: SNR 1.0 for
    its cross FRFs too), still fails: its drive points read as low."""
    k = np.array([[2.0, -1.0], [-1.0, 1.0]])
    M, K = np.eye(4), np.zeros((4, 4))
    K[:2, :2], K[2:, 2:] = 1e4 * k, 1.7e4 * k
    C = 1e-3 * K + 0.2 * M
    labels = ["1+X", "2+X", "1+Z", "2+Z"]
    frf = accelerance_from_model(M, C, K, labels, np.linspace(1.0, 60.0, 400), labels, ["1+X", "1+Z"])
    sigma = 1e-3 * np.abs(frf.H).max()
    rng = np.random.default_rng(3)
    frf.H = frf.H + sigma * (rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape)) / np.sqrt(2)
    if stated:
        frf.H_var = np.full(frf.H.shape, sigma**2)
    (pair,) = reciprocity_check(frf)
    assert pair.noise_only and pair.reciprocal and max(pair.snr) < 2 and pair.cross_to_drive < 0.1
    assert pair.drive_snr > 10
    assert "not testable" in pair.describe() and "NOT RECIPROCAL" not in pair.describe()
    from daq.run import _reciprocity  # the run's summary counts it so too

    said = []
    summary = _reciprocity(frf, said.append)
    assert summary["n_not_reciprocal"] == 0 and summary["reciprocity"][0]["noise_only"]
    assert said == [pair.describe()]

    coarse = _chain(n_freq=12)
    coarse.H[:, :, 1] /= 1.05
    coarse.H = coarse.H + 1e-3 * np.abs(coarse.H).max() * rng.standard_normal(coarse.H.shape)
    coupled = _by_pair(coarse)[("2", "7")]
    assert not coupled.reciprocal and coupled.drive_snr < 10
