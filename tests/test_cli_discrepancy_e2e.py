"""``ssidlab discrepancy`` through the console command (subprocess, real files)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from ssid.frf import accelerance_from_model
from ssid.io import Model, read_model, write_frf, write_model
from ssid.models import example_system
from ssid.noise import report_noise_frf


def run(*args):
    return subprocess.run([sys.executable, "-m", "ssidlab", *args], capture_output=True,
                          text=True, timeout=600)


def test_hidden_added_mass_is_named_and_the_gap_shrinks(tmp_path):
    M, C, K, dofs = example_system(8, seed=2)
    write_model(str(tmp_path / "nominal.h5"), Model(M=M, K=K, C=C, dofs=dofs))
    Mt = M.copy()
    Mt[3, 3] += 0.25  # a 0.25 kg accelerometer/cable mass the model lacks, at 4+Z
    outputs = [dofs[i] for i in (0, 2, 3, 5, 7)]
    clean = accelerance_from_model(Mt, C, K, dofs, np.linspace(5, 500, 600), outputs,
                                   [dofs[2], dofs[5]])
    write_frf(str(tmp_path / "measured.h5"), report_noise_frf(clean, seed=7))
    p = run("discrepancy", "--model", str(tmp_path / "nominal.h5"), "--measured",
            str(tmp_path / "measured.h5"), "--json", str(tmp_path / "out.json"), "--out",
            str(tmp_path / "updated.h5"))
    assert p.returncode == 0, p.stderr
    res = json.loads((tmp_path / "out.json").read_text())
    for key in ("effect", "dofs", "parameters", "gap_before", "gap_after", "gap_metric", "candidates"):
        assert key in res
    assert res["effect"] == "added_mass"
    assert res["dofs"] == ["4+Z"]
    assert abs(res["parameters"]["mass_kg"] - 0.25) < 0.05
    assert res["gap_after"] < 0.5 * res["gap_before"]
    upd = read_model(str(tmp_path / "updated.h5"))
    assert upd.dofs == dofs and abs(upd.M[3, 3] - Mt[3, 3]) < 0.05


def test_discrepancy_bad_input_is_one_line_and_status_2(tmp_path):
    p = run("discrepancy", "--model", str(tmp_path / "missing.h5"), "--measured",
            str(tmp_path / "missing2.h5"), "--json", str(tmp_path / "o.json"))
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
