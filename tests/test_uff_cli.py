"""``ssidlab convert``: directions, options, and one-line errors with exit status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import chain_frf, chain_model, full_frf
from test_uff_units import G, labelled_file

from ssid.exchange import (
    modes_from_model,
    read_uff_frf,
    read_uff_geometry,
    read_uff_modes,
)
from ssid.io import read_frf, write_frf, write_model
from ssidlab import cli
from ssidlab.cli_convert import add_convert_subcommand

pytest.importorskip("pyuff")


@pytest.fixture
def ssidlab(monkeypatch, capsys):
    """Run ``ssidlab ...``; wires ``convert`` in when cli.py does not list it (yet)."""
    _, subcommands = cli._build_parser()
    if "convert" not in subcommands:
        monkeypatch.setattr(cli, "_SUBCOMMANDS", cli._SUBCOMMANDS + (add_convert_subcommand,))

    def run(*argv):
        status = cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return status, out, err

    return run


def test_frf_to_uff_and_back(tmp_path, ssidlab):
    frf = full_frf()
    write_frf(tmp_path / "frf.h5", frf)
    status, out, err = ssidlab("convert", tmp_path / "frf.h5", tmp_path / "frf.uff")
    assert status == 0 and "58 (ASCII)" in out and err == ""
    status, out, _ = ssidlab("convert", tmp_path / "frf.uff", tmp_path / "back.h5")
    assert status == 0 and "1 blanked" in out
    back = read_frf(tmp_path / "back.h5")
    assert back.outputs == frf.outputs and back.reactions == frf.reactions
    np.testing.assert_array_equal(back.valid, frf.valid)


def test_the_summary_counts_the_frfs_written(tmp_path, ssidlab):
    frf = full_frf()
    frf.valid[:, 1, 0] = False  # one pair blanked throughout: not written
    write_frf(tmp_path / "frf.h5", frf)
    n = frf.n_out * frf.n_in
    status, out, _ = ssidlab("convert", tmp_path / "frf.h5", tmp_path / "frf.uff")
    assert status == 0 and f"{n - 1} FRFs (of {n}: the others are blanked)" in out, out
    frf.valid[:] = False
    write_frf(tmp_path / "none.h5", frf)
    status, _, err = ssidlab("convert", tmp_path / "none.h5", tmp_path / "none.uff")
    assert status == 2 and "no FRF has two valid lines" in err and not (tmp_path / "none.uff").exists()


def test_binary_and_geometry_options(tmp_path, ssidlab):
    write_frf(tmp_path / "frf.h5", full_frf())
    (tmp_path / "nodes.csv").write_text("node,x,y,z\n1,0,0,0\n2,0.1,0,0\n3,0.2,0,0.05\n")
    status, out, _ = ssidlab("convert", tmp_path / "frf.h5", tmp_path / "frf.unv", "--binary",
                             "--geometry", tmp_path / "nodes.csv")
    assert status == 0 and "58b" in out
    assert read_uff_geometry(tmp_path / "frf.unv")[3][2] == 0.05
    np.testing.assert_array_equal(read_uff_frf(tmp_path / "frf.unv").H_reaction,
                                  full_frf().H_reaction)


def test_model_and_result_to_mode_shapes(tmp_path, ssidlab):
    m = chain_model()
    write_model(tmp_path / "model.h5", m)
    assert ssidlab("convert", tmp_path / "model.h5", tmp_path / "modes.uff")[0] == 0
    assert read_uff_modes(tmp_path / "modes.uff", dofs=m.dofs).natural_freq_hz.size == 3
    result = {"natural_freq_hz": [5.0], "damping_ratio": [0.02], "dofs": m.dofs,
              "mode_shapes": {"real": [[1.0], [0.5], [0.25]], "imag": [[0.0], [0.1], [0.0]]}}
    (tmp_path / "result.json").write_text(json.dumps(result))
    status, out, _ = ssidlab("convert", tmp_path / "result.json", tmp_path / "r.uff")
    assert status == 0 and "1 identified modes" in out
    back = read_uff_modes(tmp_path / "r.uff", dofs=m.dofs)
    np.testing.assert_allclose(back.mode_shapes[:, 0], [1.0, 0.5 + 0.1j, 0.25], atol=1e-6)


def test_a_result_with_a_null_mode_keeps_the_numbers_of_the_others(tmp_path, ssidlab):
    """RESULT.json with mode 2 of 3 undetermined (null): mode 3 was written as 'Mode 2',
    mode number 2, and the summary did not say that a mode was left out (QA)."""
    m = chain_model()
    modes = modes_from_model(m.M, m.C, m.K, m.dofs)
    f, z = modes.natural_freq_hz.tolist(), modes.damping_ratio.tolist()
    result = {"natural_freq_hz": [f[0], None, f[2]], "damping_ratio": [z[0], None, z[2]],
              "dofs": m.dofs, "mode_shapes": {"real": modes.mode_shapes.real.tolist(),
                                              "imag": modes.mode_shapes.imag.tolist()}}
    (tmp_path / "result.json").write_text(json.dumps(result))
    status, out, _ = ssidlab("convert", tmp_path / "result.json", tmp_path / "r.uff")
    assert status == 0 and "2 identified modes" in out
    assert "numbered as in result.json" in out and "mode 2)" in out
    import pyuff

    sets = [d for d in pyuff.UFF(str(tmp_path / "r.uff")).read_sets() if d["type"] == 55]
    assert [(d["mode_n"], d["id1"].strip()) for d in sets] == [(1, "Mode 1"), (3, "Mode 3")]
    back = read_uff_modes(tmp_path / "r.uff", dofs=m.dofs)
    np.testing.assert_array_equal(back.numbers(), [1, 3])
    np.testing.assert_allclose(back.natural_freq_hz, [f[0], f[2]], rtol=1e-5)


@pytest.mark.parametrize("case, expected", [
    (("missing.uff", "out.h5"), "no such file"),
    (("frf.h5", "out.txt"), "cannot tell the output format"),
    (("frf.h5", "out.h5"), "cannot convert"),
    (("garbage.uff", "out.h5"), "not a UFF file"),
    (("frf.h5", "out.uff", "--geometry", "missing.csv"), "geometry"),
    (("frf.h5", "out.uff", "--geometry", "bad.csv"), "node,x,y,z"),
    (("model.h5", "out.uff", "--binary"), "--binary"),
    (("frf.h5", "out.uff", "--bogus"), "unrecognized arguments"),
    (("frf.h5", "frf.h5"), "overwrite the input"),
])
def test_bad_input_is_one_line_and_status_2(tmp_path, ssidlab, case, expected):
    write_frf(tmp_path / "frf.h5", full_frf())
    write_model(tmp_path / "model.h5", chain_model())
    (tmp_path / "garbage.uff").write_text("not a universal file\n")
    (tmp_path / "bad.csv").write_text("1,0,0\n")
    status, _, err = ssidlab("convert", *[tmp_path / a if not a.startswith("-") else a
                                          for a in case])
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("ssidlab convert: error: ")
    assert expected in err
    assert not (tmp_path / "out.h5").exists() and not (tmp_path / "out.uff").exists()


def test_labels_without_node_direction_fail_cleanly(tmp_path, ssidlab):
    frf = full_frf()
    frf.outputs = ["drive", "2+Z", "3+Z"]
    frf.inputs = ["drive", "3+Z"]
    frf.reactions = ["drive"]
    write_frf(tmp_path / "frf.h5", frf)
    status, _, err = ssidlab("convert", tmp_path / "frf.h5", tmp_path / "out.uff")
    assert status == 2 and "'drive'" in err and err.count("\n") == 1


def test_unit_labels_convert_and_warn_in_one_line_each(tmp_path, ssidlab):
    """A lab file in g per N without a 164 becomes SI in the FRF file; an unknown abscissa
    label is one warning line; an unknown FRF label, or a label contradicting its axis, is a
    one-line error, status 2."""
    frf = chain_frf(n_freq=8)
    labelled_file(tmp_path / "g.uff", frf, ordinate="g", scale=G, units_164=False)
    status, _, err = ssidlab("convert", tmp_path / "g.uff", tmp_path / "g.h5")
    assert status == 0 and err == ""
    np.testing.assert_allclose(read_frf(tmp_path / "g.h5").H, frf.H, rtol=1e-14)
    labelled_file(tmp_path / "odd.uff", frf, abscissa="cycles/sec")
    status, _, err = ssidlab("convert", tmp_path / "odd.uff", tmp_path / "odd.h5")
    assert status == 0 and err.count("\n") == 1 and err.startswith("warning: ")
    assert "'cycles/sec' not recognised" in err
    labelled_file(tmp_path / "poundal.uff", frf, denominator="poundal")
    status, _, err = ssidlab("convert", tmp_path / "poundal.uff", tmp_path / "poundal.h5")
    assert status == 2 and err.count("\n") == 1
    assert "'poundal' is not a unit ssidlab knows" in err
    labelled_file(tmp_path / "bad.uff", frf, ordinate="mm/s")
    status, _, err = ssidlab("convert", tmp_path / "bad.uff", tmp_path / "bad.h5")
    assert status == 2 and err.count("\n") == 1 and "'mm/s' is a velocity unit" in err
