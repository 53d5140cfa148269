"""Modes that share a frequency (rigid-body modes, a symmetric structure's pairs) are compared
as subspaces, rigid-body pairs have no percentage error, and every test mode is paired or
listed in ``not_paired`` (QA of ``ssidlab correlate``: a free-free beam against its own exact
TAM failed its cross-orthogonality, and a rigid-body test mode vanished from the report)."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest
import scipy.linalg as sla
from test_correlate_cli import run
from test_tam_models import beam_model, translations

from ssid.correlate_models import correlate_models
from ssid.correlate_pairs import mode_correlation
from ssid.io import Model, write_model
from ssid.tam import reduce_to_tam


def _free_beam():
    """Free-free beam, 8 elements, measured in Z at 5 nodes: 2 rigid-body modes at 0 Hz."""
    M, K, dofs = beam_model(n_elem=8, length_m=1.0, k_ground_n_per_m=(0.0, 0.0))
    return M, K, dofs, translations(dofs, [1, 3, 5, 7, 9])


def _tower(asymmetry: float = 0.0):
    """The x and y chains of one tower, uncoupled: each frequency twice (split by
    ``asymmetry``, a relative change of the y chain's masses)."""
    m = np.eye(3)
    k = 1e3 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    return (sla.block_diag(m, (1 + asymmetry) * m), sla.block_diag(k, k),
            ["1+X", "2+X", "3+X", "1+Y", "2+Y", "3+Y"])


def test_frequency_groups_are_the_modes_at_rest_and_each_repeated_root():
    from ssid.correlate_groups import REPEATED_FREQ_RTOL, frequency_groups

    f = np.array([-2e-6, 1e-6, 10.0, 10.0 * (1 + 1e-9), 10.5, 20.0, 20.0, 20.0 * (1 + 1e-8), -3.0])
    assert [g.tolist() for g in frequency_groups(f)] == [[0, 1], [2, 3], [5, 6, 7]]
    # Split by more than the tolerance: distinct modes, no group.
    assert frequency_groups([5.0, 5.0 * (1 + 10 * REPEATED_FREQ_RTOL)]) == []


@pytest.mark.parametrize("tam", ["hybrid", "serep", "guyan", "irs"])
def test_rigid_body_modes_of_an_exact_tam_pair_as_a_subspace(tam):
    """The test model is the beam's own TAM: its rigid-body modes are the beam's, in another
    basis of the same plane. Compared one by one they had MAC 0.79/0.87 and a cross-orthogonality
    block of a pure rotation (hybrid: fail), and with Guyan one of them MAC 0.46 with
    everything and missing from both the pairs and ``not_paired``."""
    M, K, dofs, a = _free_beam()
    red = reduce_to_tam(tam, M, K, a)
    s = correlate_models(Model(red.M, red.K, None, [dofs[i] for i in a]), Model(M, K, None, dofs), tam=tam).summary
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(i, i) for i in range(1, 6)]
    assert s["not_paired"] == []
    rigid = s["paired_modes"][:2]
    assert all(p["rigid"] and np.isnan(p["freq_error_percent"]) for p in rigid)
    assert all(abs(p["freq_error_hz"]) < 1e-3 for p in rigid)
    assert all(p["mac"] > 1 - 1e-9 and abs(p["cross_orthogonality"]) > 1 - 1e-9 for p in rigid)
    assert not any(p["rigid"] for p in s["paired_modes"][2:])
    [sub] = s["subspaces"]
    assert sub["test_modes"] == sub["analysis_modes"] == sub["aligned_with"] == [1, 2] and sub["at_rest"]
    assert max(sub["principal_angles_deg"]) < 1e-6
    Q = np.asarray(sub["rotation"])
    np.testing.assert_allclose(Q.T @ Q, np.eye(2), atol=1e-12)
    if tam in ("hybrid", "serep"):  # exact for every mode: the identity
        np.testing.assert_allclose(np.abs(s["cross_orthogonality"]["paired_matrix"]), np.eye(5), atol=1e-8)
        assert s["cross_orthogonality"]["pass"]


def test_a_symmetric_towers_repeated_modes_pair_as_subspaces():
    """SEREP TAM of the tower at 4 DOFs as the test model (exact for its 4 lowest modes): MAC
    0.941 and an off-diagonal cross-orthogonality of 0.243 (fail) in the eigensolver's basis."""
    M, K, dofs = _tower()
    a = [2, 5, 1, 4]
    red = reduce_to_tam("serep", M, K, a)
    s = correlate_models(Model(red.M, red.K, None, [dofs[i] for i in a]), Model(M, K, None, dofs),
                         tam="serep").summary
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(1, 1), (2, 2), (3, 3), (4, 4)]
    assert min(p["mac"] for p in s["paired_modes"]) > 1 - 1e-9
    assert s["cross_orthogonality"]["pass"] and s["cross_orthogonality"]["max_abs_offdiag"] < 1e-8
    assert [(g["test_modes"], g["analysis_modes"], g["at_rest"]) for g in s["subspaces"]] == [
        ([1, 2], [1, 2], False), ([3, 4], [3, 4], False)]


def test_split_test_frequencies_are_distinct_modes_and_not_rotated():
    """A test tower whose y chain is 0.2 % heavier: its pairs are split by 0.1 %, distinct
    modes (an x mode and a y mode), compared as they are; the analysis pairs, an arbitrary
    basis of their roots, are turned onto them instead (the 9.1 Hz pair, which holds 64 % of
    the 6.3 Hz test modes but is not their match, is left alone)."""
    M, K, dofs = _tower()
    Mt, Kt, _ = _tower(asymmetry=2e-3)
    a = [2, 5, 1, 4]
    red = reduce_to_tam("serep", Mt, Kt, a)
    s = correlate_models(Model(red.M, red.K, None, [dofs[i] for i in a]), Model(M, K, None, dofs),
                         tam="serep").summary
    assert [(g["rotated"], g["test_modes"], g["analysis_modes"]) for g in s["subspaces"]] == [
        ("analysis", [1, 2], [1, 2]), ("analysis", [3, 4], [3, 4])]
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(1, 1), (2, 2), (3, 3), (4, 4)]
    assert min(p["mac"] for p in s["paired_modes"]) > 1 - 1e-6


def test_a_free_beam_on_bungees_pairs_its_suspension_modes_with_the_rigid_body_modes():
    """The test measures the free-free beam on soft springs at its ends: suspension modes at
    1.06 and 1.84 Hz, split (distinct modes, not rotated). In the eigensolver's basis of the
    analysis rigid-body modes the 1.06 Hz mode had MAC 0.44 with everything, was not paired,
    and the cross-orthogonality failed (0.74); the rigid-body modes are turned onto the two."""
    M, K, dofs, a = _free_beam()
    Kt = K.copy()
    Kt[0, 0] += 60.0
    Kt[16, 16] += 60.0
    red = reduce_to_tam("guyan", M, Kt, a)
    s = correlate_models(Model(red.M, red.K, None, [dofs[i] for i in a]), Model(M, K, None, dofs)).summary
    assert s["test_natural_freq_hz"][:2] == pytest.approx([1.06, 1.84], abs=0.01)
    [g] = s["subspaces"]
    assert (g["rotated"], g["test_modes"], g["analysis_modes"], g["at_rest"]) == ("analysis", [1, 2], [1, 2], True)
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(i, i) for i in range(1, 6)]
    assert min(p["mac"] for p in s["paired_modes"][:2]) > 0.999 and s["cross_orthogonality"]["pass"]
    from ssidlab.cli_correlate import pair_table

    table = pair_table({"tam": "guyan", **s}).splitlines()
    k = table.index("analysis modes 1, 2 (at rest) share a frequency, test modes 1, 2 do not (distinct modes): "
                    "compared as subspaces")
    assert table[k + 1].endswith("analysis modes rotated within their span onto test modes 1, 2 (TAM mass)")


def test_every_test_mode_is_paired_or_said_why_not():
    """At 3 DOFs: test modes e1, e1 + 0.1 e2 (normalised), e3; analysis modes e1 and
    (e1 + e2 + e3)/sqrt(3). Test mode 2's best match is taken by test mode 1, test mode 3 has
    MAC 1/3 at best: neither was listed anywhere."""
    e = np.eye(3)
    phi_t = np.c_[e[:, 0], (e[:, 0] + 0.1 * e[:, 1]) / np.hypot(1, 0.1), e[:, 2]]
    phi_a = np.c_[e[:, 0], np.ones(3) / np.sqrt(3)]
    s, _, pairs = mode_correlation(phi_t, np.array([10.0, 11.0, 12.0]), phi_a, np.array([10.0, 12.0]), np.eye(3))
    assert [(p.test, p.analysis) for p in pairs] == [(0, 0)]
    why = {p["test_mode"]: (p["analysis_mode"], p["reason"]) for p in s["not_paired"]}
    assert why[2] == (1, "analysis mode 1 is paired with test mode 1 (MAC 1.000): pairs are one to one")
    assert why[3][0] == 2 and why[3][1].startswith("no analysis mode has a MAC of 0.5 or more")
    assert sorted(why) == [2, 3]


def _correlate_free_beam_with_its_guyan_tam(tmp_path):
    """``ssidlab correlate`` of the free beam's Guyan TAM (test) against the beam; its JSON."""
    M, K, dofs, a = _free_beam()
    red = reduce_to_tam("guyan", M, K, a)
    write_model(tmp_path / "test.h5", Model(red.M, red.K, None, [dofs[i] for i in a]))
    write_model(tmp_path / "fem.h5", Model(M, K, None, dofs))
    js = tmp_path / "c.json"
    argv = ["--model", str(tmp_path / "test.h5"), "--model", str(tmp_path / "fem.h5"), "--json", str(js)]
    assert run(argv) == (0, "")
    return js


def test_rigid_pairs_print_as_rigid_and_their_subspace_is_shown(tmp_path, capsys):
    js = _correlate_free_beam_with_its_guyan_tam(tmp_path)
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[4] for line in out[2:4]] == ["rigid", "rigid"]
    k = out.index("rigid: paired with an analysis mode at 0 Hz (rigid-body), whose error is no percentage")
    assert out[k + 1] == "test modes 1, 2 (at rest) share a frequency, as analysis modes 1, 2 do: compared as subspaces"
    assert out[k + 2].startswith("  principal angles ") and "onto analysis modes 1, 2 (TAM mass)" in out[k + 2]
    s = json.loads(js.read_text())
    assert s["freq_error_percent"][:2] == [None, None] and s["paired_modes"][0]["freq_error_percent"] is None


def test_rigid_pairs_get_no_bar_on_the_percentage_axis(tmp_path, monkeypatch):
    """freq_errors.png drew the round-off of two rigid-body pairs as -107 % and -88 % bars."""
    from ssid.plots_correlation import plot_frequency_errors

    matplotlib.use("Agg")
    from matplotlib.axes import Axes

    heights = []
    real_bar = Axes.bar

    def bar(self, x, height, *args, **kwargs):
        heights.extend(np.atleast_1d(height).tolist())
        return real_bar(self, x, height, *args, **kwargs)

    monkeypatch.setattr(Axes, "bar", bar)
    pairs = [{"test_mode": 1, "analysis_mode": 2, "mac": 1.0, "freq_error_percent": -107.3, "rigid": True,
              "freq_error_hz": 1e-6},
             {"test_mode": 3, "analysis_mode": 3, "mac": 1.0, "freq_error_percent": 0.4, "rigid": False}]
    plot_frequency_errors(pairs, tmp_path / "f.png")
    assert heights == [0.4]


def test_a_low_elastic_mode_keeps_its_percentage_error():
    """Only an analysis mode at 0 Hz to round-off is rigid: a payload's 1.29 Hz mode beside
    2600 Hz (omega^2 ratio 2.5e-7, at rest by the pairing's looser bound) has a real error
    against a 1.26 Hz test mode, -2.3 % (the lab demo printed "rigid" for it)."""
    phi = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))[0]
    f_an = np.array([1.29, 1000.0, 2600.0])
    f_t = np.array([1.26, 1000.0, 2600.0])
    s, _, _ = mode_correlation(phi, f_t, phi, f_an, np.eye(3))
    first = s["paired_modes"][0]
    assert not first["rigid"] and first["freq_error_percent"] == pytest.approx(100 * (1.26 / 1.29 - 1))


def test_a_hybrid_tam_whose_targets_leave_out_the_rigid_body_modes_is_warned_of():
    """Targets 3-5 on the free beam: the hybrid TAM's rigid-body modes moved to 0.97 and 8.0 Hz
    (its projector does not vanish on a rigid motion), without a word. With the rigid modes
    among the targets they stay at 0 Hz, and nothing is said."""
    M, K, dofs, a = _free_beam()
    red = reduce_to_tam("guyan", M, K, a)
    test, fem = Model(red.M, red.K, None, [dofs[i] for i in a]), Model(M, K, None, dofs)
    s = correlate_models(test, fem, tam="hybrid", targets=[3, 4, 5]).summary
    assert min(s["tam_natural_freq_hz"][:2]) > 0.5
    assert ("the hybrid TAM's target modes leave out analysis modes 1, 2, at rest (rigid-body): the TAM moves them "
            "off 0 Hz") in " ".join(s["warnings"])
    s = correlate_models(test, fem, tam="hybrid", targets=[1, 2, 3, 4, 5]).summary
    assert max(np.abs(s["tam_natural_freq_hz"][:2])) < 1e-3 and not any("leave out" in w for w in s["warnings"])


def test_modes_at_rest_print_as_zero_without_a_sign_and_label_the_mac_plot_as_zero(tmp_path, capsys, monkeypatch):
    """Rigid-body test modes printed as "-0.0000" Hz, and mac.png's labels of the analysis
    modes' round-off ("-8.123e-06") overlapped."""
    from matplotlib.axes import Axes

    from ssid.plots_correlation import plot_mac_matrix

    js = _correlate_free_beam_with_its_guyan_tam(tmp_path)
    out = capsys.readouterr().out
    assert "-0.0000" not in out
    s = json.loads(js.read_text())
    assert min(s["test_natural_freq_hz"][:2]) < 0 and min(s["analysis_natural_freq_hz"][:2]) < 0  # round-off
    assert [line.split()[1] for line in out.splitlines()[2:4]] == ["0.0000", "0.0000"]
    labels = []
    real = Axes.set_xticks

    def set_xticks(self, ticks, tick_labels=None, **kwargs):
        labels.extend(tick_labels or [])
        return real(self, ticks, tick_labels, **kwargs)

    monkeypatch.setattr(Axes, "set_xticks", set_xticks)
    plot_mac_matrix(np.asarray(s["mac"]), tmp_path / "mac.png", s["test_natural_freq_hz"],
                    s["analysis_natural_freq_hz"])
    assert labels[:3] == ["1\n0", "2\n0", f"3\n{s['analysis_natural_freq_hz'][2]:.4g}"]


def test_suspension_modes_at_different_frequencies_are_not_one_repeated_root():
    """A free beam hung on bungees near its centre (pitch 0.46 Hz below bounce 1.06 Hz)
    against a model with the bungees at its ends (bounce 0.61 Hz below pitch 1.06 Hz), in a
    2 kHz band. Counted at rest by the pairing's bound (frequencies up to 1e-3 of the highest),
    both sets' suspension modes were one "repeated root", rotated onto each other: MAC 1.000
    for modes 57 % and 73 % apart, where pitch pairs with pitch. Only modes at 0 Hz to
    round-off share a frequency as rigid-body modes."""
    from ssid.correlate_groups import frequency_groups

    def beam(springs):
        M, K, dofs = beam_model(n_elem=8, length_m=1.0, ei_n_m2=3.2e4, k_ground_n_per_m=(0.0, 0.0))
        for node, k in springs.items():
            i = dofs.index(f"{node}+Z")
            K[i, i] += k
        return M, K, dofs

    Mt, Kt, dofs = beam({4: 60.0, 6: 60.0})
    Ma, Ka, _ = beam({1: 20.0, 9: 20.0})
    a = [dofs.index(f"{k}+Z") for k in (1, 3, 5, 7, 9)]
    red = reduce_to_tam("serep", Mt, Kt, a)
    f_test = np.sqrt(sla.eigh(red.K, red.M, eigvals_only=True)) / (2 * np.pi)
    assert f_test[1] < 1.1 and f_test[-1] > 1900 and frequency_groups(f_test) == []
    res = correlate_models(Model(red.M, red.K, None, [dofs[i] for i in a]), Model(Ma, Ka, None, dofs))
    pairs = res.summary["paired_modes"][:2]
    assert [(p["test_mode"], p["analysis_mode"]) for p in pairs] == [(1, 2), (2, 1)], pairs
    assert not res.summary["subspaces"]
