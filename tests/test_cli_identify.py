"""``ssidlab identify`` and ``ssidlab demo`` run as a user runs them (subprocess, real files)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from ssid.frf import accelerance_from_model
from ssid.io import read_model, write_frf
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "ssidlab", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


def test_identify_writes_contract_model_and_json(tmp_path):
    M, C, K, dofs = example_system(6, seed=3)
    order = [dofs[i] for i in (3, 0, 5, 1, 4, 2)]  # outputs in a non-sorted order
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(3, 450, 400), order, [dofs[0], dofs[4]])
    src = tmp_path / "frf.h5"
    write_frf(str(src), frf)
    out, js = tmp_path / "model.h5", tmp_path / "result.json"
    p = run("identify", str(src), "--out", str(out), "--json", str(js))
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    model = read_model(str(out))
    assert model.dofs == order
    perm = [dofs.index(lbl) for lbl in order]
    assert np.allclose(model.M, M[np.ix_(perm, perm)], rtol=1e-6, atol=1e-8 * np.abs(M).max())
    assert np.allclose(model.K, K[np.ix_(perm, perm)], rtol=1e-6, atol=1e-8 * np.abs(K).max())
    res = json.loads(js.read_text())
    lam, _ = complex_modes(M, C, K)
    f_true = root_frequency_damping(lam)[0] / (2 * np.pi)
    assert res["dofs"] == order
    assert np.all(np.diff(res["natural_freq_hz"]) > 0)
    assert np.allclose(res["natural_freq_hz"], f_true, rtol=1e-6)
    assert len(res["damping_ratio"]) == len(res["natural_freq_hz"])


def test_identify_select_band_for_a_reduced_order_model(tmp_path):
    """4 sensors, 7 modes in the band (test_identify's case: 3 of them belong to unmeasured
    structure). ``--select-band`` returns a physical 4-DOF model whose modes are the 4-DOF
    system's own within 1 % (the report's criterion for an identified mode), and says how the
    band and solver were chosen; --solver with it is refused as the contradiction it is."""
    from test_identify import _four_dof_with_unmeasured_modes, true_frequencies_hz

    (M, C, K), frf = _four_dof_with_unmeasured_modes(3)
    src = tmp_path / "frf.h5"
    write_frf(str(src), frf)
    out, js = tmp_path / "model.h5", tmp_path / "result.json"
    p = run("identify", str(src), "--out", str(out), "--json", str(js), "--select-band")
    assert p.returncode == 0, p.stderr
    # A physical choice is reported on stdout, not as a warning.
    assert "band and solver chosen from the data" in p.stdout
    assert "(physical, " in p.stdout and "warning" not in p.stderr
    model = read_model(str(out))
    assert np.linalg.eigvalsh(model.M).min() > 0 and np.linalg.eigvalsh(model.K).min() > 0
    res = json.loads(js.read_text())
    f_sys, _ = true_frequencies_hz(M, C, K)
    np.testing.assert_allclose(res["natural_freq_hz"], f_sys, rtol=0.01)
    bad = run("identify", str(src), "--out", str(tmp_path / "m2.h5"), "--json",
              str(tmp_path / "r2.json"), "--select-band", "--solver", "tls")
    assert bad.returncode != 0 and "Traceback" not in bad.stderr
    assert "--select-band chooses the solver" in bad.stderr


def test_example_demo_end_to_end(tmp_path):
    p = run("demo", "--example", "--out", str(tmp_path / "demo"))
    assert p.returncode == 0, p.stderr
    for name in ("frf.h5", "model.h5", "result.json", "frf_overlay.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 0
    res = json.loads((tmp_path / "demo" / "result.json").read_text())
    assert res["demo"]["max_abs_freq_error_percent"] < 1.0


def test_lab_demo_end_to_end(tmp_path):
    """The main job, README line 1, as written: the installed ``ssidlab`` command (the
    console script beside this interpreter, as ``pip install .`` makes it) runs the simulated
    lab, stepped sine, SSID with reactions, correlation and discrepancy. ``.ci/run`` relies
    on this test for that line instead of running the demo a second time."""
    script = Path(sys.executable).with_name("ssidlab")
    assert script.exists(), f"no ssidlab console script beside {sys.executable}: install the project (pip install .)"
    p = subprocess.run([str(script), "demo", "--out", str(tmp_path / "lab")], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    out = tmp_path / "lab"
    for name in ("frf.h5", "model.h5", "result.json", "summary.json", "correlation.json",
                 "frf_overlay.png", "mac.png", "discrepancy.json", "updated_model.h5"):
        assert (out / name).stat().st_size > 0, name
    from ssid.io import read_frf

    frf = read_frf(str(out / "frf.h5"))
    assert frf.H_reaction is not None and frf.n_in == 2 and frf.n_out == 16
    assert "Traceback" not in p.stderr
    summary = json.loads((out / "summary.json").read_text())
    ident = summary["identification"]
    assert ident["max_abs_freq_error_in_band_percent"] < 0.1  # low sensor noise: see docs
    # The discrepancy workflow names the effect hidden in the simulated lab (0.25 kg at 6+Z).
    disc = summary["discrepancy"]
    assert disc["effect"] == "added_mass" and disc["dofs"] == ["6+Z"]
    assert abs(disc["parameters"]["mass_kg"] - 0.25) < 0.05
    assert disc["gap_after"] < 0.5 * disc["gap_before"]
    # And from the FE payload model alone, loaded by the measured reactions (no stand model).
    sub = summary["discrepancy_substructure"]
    assert sub["reactions"]["applied"] and (sub["effect"], sub["dofs"]) == ("added_mass", ["6+Z"])
    assert abs(sub["parameters"]["mass_kg"] - 0.25) < 0.05 and sub["gap_after"] < 0.5 * sub["gap_before"]
    # The printed table pairs each identified mode with its FE mode by MAC, as correlation.json
    # does (the hidden mass swaps the close pair's order), not by mode number.
    pairs = {m["test_mode"]: m["analysis_mode"]
             for m in json.loads((out / "correlation.json").read_text())["paired_modes"]}
    rows = {int(c[0]): int(c[5]) for c in (line.split() for line in p.stdout.splitlines())
            if len(c) == 9 and c[0].isdigit() and c[5].isdigit()}
    assert rows and rows == pairs


def test_mode_table_pairs_rows_only_where_they_are_the_same_modes():
    """The QA's random record: 15 roots, and the written M, K's 16 undamped frequencies begin
    with two negative eigenvalues. They were printed as -12408.78 and -8.42 Hz beside the
    roots at 4.3 and 6.2 Hz, every later row one mode apart. Now the roots stand alone, the
    M, K frequencies follow on their own line, and the negative eigenvalues as omega^2."""
    from ssidlab.cli_identify import _mode_table

    roots = [4.2943, 6.2017, 13.3771, 78.4795, 115.2879, 145.0129, 304.7151, 318.0687, 393.1732,
             559.9941, 696.1861, 778.0534, 1197.6195, 1763.9367, 2211.1081]
    undamped = [-12408.7754, -8.4215, 6.1983, 15.1541, 16.4182, 78.4743, 116.2066, 145.2343, 315.6377,
                319.1419, 395.5235, 573.8182, 767.1130, 881.7112, 1202.2671, 1785.1532]
    table = _mode_table({"natural_freq_hz": roots, "damping_ratio": [0.02] * 15, "undamped_freq_hz": undamped,
                         "n_rigid_body_modes": 0}).splitlines()
    assert table[0].split() == ["mode", "f_n", "[Hz]", "damping", "[%]"]
    assert table[1].split() == ["1", "4.2943", "2.000"] and "-12408" not in "\n".join(table[:16])
    assert table[16].startswith("M,K f [Hz]: the written M, K's undamped frequencies, 14 for 15 roots, so "
                                "not paired with them row by row: 6.1983, 15.1541,")
    assert table[17].startswith("(K, M) also has 2 negative eigenvalue(s), omega^2 = -6.079e+09, -2800 (rad/s)^2")
    # One elastic mode per root and none negative: side by side, as the guide shows; rigid-body
    # rows first. M not positive definite (every value null): the column shows "-".
    table = _mode_table({"natural_freq_hz": [1.26, 78.39], "damping_ratio": [0.02, 0.02],
                         "undamped_freq_hz": [0.0, 1.2586, 78.3924], "n_rigid_body_modes": 1}).splitlines()
    assert [row.split() for row in table[1:]] == [["R1", "rigid", "body", "-", "0.0000"],
                                                  ["1", "1.2600", "2.000", "1.2586"],
                                                  ["2", "78.3900", "2.000", "78.3924"]]
    table = _mode_table({"natural_freq_hz": [1.26], "damping_ratio": [0.02], "undamped_freq_hz": [None, None]})
    assert table.splitlines()[1].split() == ["1", "1.2600", "2.000", "-"]
