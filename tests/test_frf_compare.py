"""Two measurements of one structure's FRFs (ssid.frf_compare, ``ssidlab compare``): the
14-DOF example chain synthesised from its M, C, K for the physics, then two simulated
stepped-sine tests through the real drivers - at two force levels (the simulated structure
is linear: they agree) and before and after a 0.3 kg mass is added (they do not)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ssid.errors import InputError
from ssid.frf import FRFData, accelerance_from_model
from ssid.frf_compare import SHAPE_TOLERANCE, compare_frfs
from ssid.io import write_frf
from ssid.models import example_system
from ssidlab.cli import main

from test_daq_helpers import cli, sine_setup
from test_reciprocity import _noisy, _uncoupled_xz

F = np.linspace(2.0, 400.0, 400)


def _chain(K_scale: float = 1.0, freq_hz: np.ndarray = F) -> FRFData:
    M, C, K, dofs = example_system(14, seed=1)
    labels = [str(k) for k in range(len(dofs))]
    return accelerance_from_model(M, C, K_scale * K, labels, freq_hz, labels, ["2", "7"])


@pytest.mark.parametrize("seed", [1, 2])
def test_two_noisy_measurements_of_one_structure_agree_and_a_stiffer_one_does_not(seed):
    """1 % noise on each (stated in H_var, the noise model of test_reciprocity): every one of
    the 28 FRFs agrees. The same structure 2 % stiffer (a joint at another level: every
    resonance 1 % higher) differs in shape at every FRF. A force gauge 5 % off in one test
    is a gain of 1/1.05 on its input's FRFs and nothing else."""
    a, b = _noisy(_chain(), 0.01, seed), _noisy(_chain(), 0.01, seed + 10)
    same = compare_frfs(a, b)
    assert same.n_compared() == 28 and same.disagreeing() == []
    stiff = compare_frfs(a, _noisy(_chain(1.02), 0.01, seed + 10)).disagreeing()
    assert len(stiff) == 28 and all(not c.shape_ok for _, _, c in stiff)
    off = _chain()
    off.H[:, :, 1] /= 1.05
    found = compare_frfs(_noisy(off, 0.01, seed), b).disagreeing()
    assert {i for _, i, _ in found} == {"7"} and len(found) == 14
    assert all(c.shape_ok and abs(c.gain - 1 / 1.05) < 0.005 for _, _, c in found)


def test_an_frf_zero_in_both_records_agrees_and_one_zero_in_one_record_does_not():
    """Directions that do not couple: the cross FRFs are zero in both runs, the same curve,
    and were listed as disagreeing (a dead channel?) like the reciprocity check's (QA). Zero in
    one run only is still a disagreement."""
    a = _uncoupled_xz()
    cmp = compare_frfs(a, _uncoupled_xz())
    assert cmp.n_compared() == 8 and cmp.disagreeing() == []
    c = cmp.curves[cmp.outputs.index("1+X")][cmp.inputs.index("1+Z")]
    assert c.both_zero and c.agree and not c.dead and c.describe() == "both zero at every line"
    b = _uncoupled_xz()
    b.H[:, b.outputs.index("1+X"), b.inputs.index("1+Z")] = 1e-3  # responds in one record only
    (found,) = compare_frfs(a, b).disagreeing()
    assert found[:2] == ("1+X", "1+Z") and found[2].dead and not found[2].both_zero


def test_a_shape_difference_must_matter_as_well_as_stand_out_of_the_noise():
    """Stated noise 1e-7 of each value (plus the floor of 1e-6 of the largest), as quiet as
    a noise-free simulation. A structure 1e-5 stiffer (resonances 5e-6 higher) leaves 1e-4
    of the FRF after the gain, 7 or more times the stated noise: it is not a finding
    (``SHAPE_TOLERANCE``, 1e-3 of the FRF). 1e-3 stiffer (resonances 0.05 % higher) leaves
    1 % and differs at every FRF."""
    a = _noisy(_chain(), 1e-7, 1)
    tiny = [c for row in compare_frfs(a, _noisy(_chain(1 + 1e-5), 1e-7, 2)).curves for c in row]
    assert all(c.residual_ratio > 3 and c.relative_residual < SHAPE_TOLERANCE / 3 for c in tiny)
    assert all(c.agree for c in tiny)
    small = [c for row in compare_frfs(a, _noisy(_chain(1 + 1e-3), 1e-7, 2)).curves for c in row]
    assert all(c.relative_residual > 5 * SHAPE_TOLERANCE and not c.shape_ok for c in small)


def test_files_with_other_lines_are_compared_on_the_lines_they_share():
    a = _chain()
    b = _chain(freq_hz=np.concatenate([F[::2], [401.0, 402.0]]))  # every other line, and two more
    cmp = compare_frfs(a, b)
    assert np.array_equal(cmp.freq_hz, F[::2]) and cmp.disagreeing() == []
    with pytest.raises(InputError, match="no frequency line in common"):
        compare_frfs(a, _chain(freq_hz=F + 0.5))
    other = FRFData(F, a.H, [f"x{k}" for k in a.outputs], [f"x{k}" for k in a.inputs])
    with pytest.raises(InputError, match="no output and input DOF labels"):
        compare_frfs(a, other)
    # Lines in common, but blanked in one file wherever the other has them: nothing to
    # compare, which is no agreement ("all 0 FRFs agree", exit 0, until QA found it).
    blanked = _chain()
    valid = np.ones(blanked.H.shape, dtype=bool)
    valid[::2] = False
    blanked.H[::2] = np.nan
    blanked.valid = valid
    with pytest.raises(InputError, match="no valid value in common"):
        compare_frfs(blanked, b)


def test_ssidlab_compare_finds_linearity_between_levels_and_a_mass_added(tmp_path, capsys):
    """Stepped-sine tests of the simulated lab with sensor noise, two shakers: at 1 N and at
    2 N the FRFs agree (the simulated structure is linear); with 0.3 kg added at 4+Z they do
    not, at the FRFs the mass changes."""
    runs = {}
    for name, force, extra in [("low", 1.0, ""), ("high", 2.0, ""),
                               ("mass", 1.0, '[[sim.effects]]\ntype = "added_mass"\ndof = "4+Z"\nmass_kg = 0.3\n')]:
        text = sine_setup(n_lines=4, two=True, noise=True).replace("force_n = 1.0", f"force_n = {force}") + extra
        (tmp_path / f"{name}.toml").write_text(text)
        runs[name] = tmp_path / f"{name}.h5"
        assert cli([str(tmp_path / f"{name}.toml"), "--sim", "--out", str(runs[name]), "--quiet"])[0] == 0
    assert main(["compare", str(runs["low"]), str(runs["high"]), "--json", str(tmp_path / "lin.json")]) == 0
    out = capsys.readouterr().out.splitlines()
    lin = json.loads((tmp_path / "lin.json").read_text())
    assert lin["agree"] and out[-1].startswith(f"all {lin['n_compared']} FRFs agree"), out
    assert lin["n_lines"] >= 10 and lin["n_compared"] == len(lin["frfs"]) > 0
    assert main(["compare", str(runs["low"]), str(runs["mass"]), "--json", str(tmp_path / "mass.json")]) == 0
    out = capsys.readouterr().out.splitlines()
    mass = json.loads((tmp_path / "mass.json").read_text())
    assert not mass["agree"] and mass["n_differ"] > mass["n_compared"] // 2, mass["verdict"]
    assert out[-1] == mass["verdict"] and any("shape differ" in line for line in out[1:-1]), out
    assert main(["compare", str(runs["low"]), str(tmp_path / "none.h5")]) == 2


def _with_reactions(frf: FRFData, seed: int, load_cell_gain: float = 1.0) -> FRFData:
    """``frf`` with two interface reactions at outputs 3 and 9 (stand-in curves, N/N: 0.5 kg
    times those outputs' accelerances), 1 % noise stated in ``H_reaction_var``, the load cell
    at 3 reading ``load_cell_gain`` times the force."""
    rng = np.random.default_rng(seed)
    true = 0.5 * _chain().H[:, [3, 9], :]
    var = (0.01 * np.abs(true)) ** 2 + (1e-6 * np.max(np.abs(true))) ** 2
    e = rng.standard_normal(true.shape) + 1j * rng.standard_normal(true.shape)
    r = true + np.sqrt(var / 2) * e
    r[:, 0, :] *= load_cell_gain
    return FRFData(frf.freq_hz, frf.H, frf.outputs, frf.inputs, H_var=frf.H_var, H_reaction=r,
                   reactions=["3", "9"], H_reaction_var=var * np.array([load_cell_gain**2, 1])[None, :, None])


def test_reactions_are_compared_like_the_accelerances(tmp_path, capsys):
    """A load cell 10 % off its calibration in one test changes its reactions only: the 28
    accelerances agree, the reactions at 3 (both inputs) differ by a gain of 1/1.1, and the
    command's verdict says so (it compared accelerances only and said "all 28 FRFs agree").
    A file whose reactions the other lacks is warned of."""
    a = _with_reactions(_noisy(_chain(), 0.01, 1), 2)
    b = _with_reactions(_noisy(_chain(), 0.01, 3), 4, load_cell_gain=1.10)
    cmp = compare_frfs(a, b)
    assert cmp.disagreeing() == [] and cmp.reactions == ["3", "9"] and cmp.n_reactions_compared() == 4
    found = cmp.disagreeing_reactions()
    assert [(r, i) for r, i, _ in found] == [("3", "2"), ("3", "7")]
    assert all(not c.gain_ok and c.shape_ok and abs(abs(c.gain) - 1 / 1.1) < 0.005 for _, _, c in found)
    assert compare_frfs(a, _with_reactions(_noisy(_chain(), 0.01, 3), 4)).disagreeing_reactions() == []
    write_frf(str(tmp_path / "a.h5"), a)
    write_frf(str(tmp_path / "b.h5"), b)
    write_frf(str(tmp_path / "free.h5"), _noisy(_chain(), 0.01, 5))
    assert main(["compare", str(tmp_path / "a.h5"), str(tmp_path / "b.h5"),
                 "--json", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out.splitlines()
    res = json.loads((tmp_path / "c.json").read_text())
    assert not res["agree"] and (res["n_reactions_compared"], res["n_reactions_differ"]) == (4, 2)
    assert out[-1] == res["verdict"] == ("0 of 28 FRFs and 2 of 4 reaction FRFs differ beyond their "
                                         "noise or the calibration tolerance over 400 common lines")
    assert any(line.startswith("  reaction 3 / 2: gain 0.9") and line.endswith("gain differ")
               for line in out), "\n".join(out)
    assert {(r["reaction"], r["agree"]) for r in res["reactions"]} == {("3", False), ("9", True)}
    assert main(["compare", str(tmp_path / "a.h5"), str(tmp_path / "free.h5")]) == 0
    cap = capsys.readouterr()
    assert f"warning: reactions only in {tmp_path / 'a.h5'}, not compared: 3, 9" in cap.err
