"""``ssidlab correlate`` through the real command line (subprocess, real files)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from ssid.frf import accelerance_from_model
from ssid.io import Model, write_frf, write_model
from ssid.models import example_system


def run(*args):
    return subprocess.run([sys.executable, "-m", "ssidlab", *args], capture_output=True,
                          text=True, timeout=600)


def test_identified_model_correlates_with_the_truth(tmp_path):
    M, C, K, dofs = example_system(6, seed=3)
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(3, 450, 400), dofs, [dofs[0], dofs[4]])
    write_frf(str(tmp_path / "frf.h5"), frf)
    write_model(str(tmp_path / "truth.h5"), Model(M=M, K=K, C=C, dofs=dofs))
    p = run("identify", str(tmp_path / "frf.h5"), "--out", str(tmp_path / "id.h5"),
            "--json", str(tmp_path / "id.json"), "--quiet")
    assert p.returncode == 0, p.stderr
    p = run("correlate", "--model", str(tmp_path / "id.h5"), "--model", str(tmp_path / "truth.h5"),
            "--json", str(tmp_path / "corr.json"), "--plots", str(tmp_path / "plots"))
    assert p.returncode == 0, p.stderr
    res = json.loads((tmp_path / "corr.json").read_text())
    pairs = res["paired_modes"]
    assert len(pairs) == 6
    assert min(pr["mac"] for pr in pairs) > 0.999
    assert max(abs(pr["freq_error_percent"]) for pr in pairs) < 1e-4
    assert any(p.suffix == ".png" for p in (tmp_path / "plots").iterdir())
    # The model against its own measured FRFs.
    p = run("correlate", "--model", str(tmp_path / "truth.h5"), "--frf", str(tmp_path / "frf.h5"),
            "--json", str(tmp_path / "corr_frf.json"))
    assert p.returncode == 0, p.stderr
    res = json.loads((tmp_path / "corr_frf.json").read_text())
    assert res["frac"]["min"] > 0.999


def test_correlate_bad_input_is_one_line_and_status_2(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_text("not hdf5")
    p = run("correlate", "--model", str(bad), "--model", str(bad), "--json", str(tmp_path / "o.json"))
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
