"""The user guide's commands run as written (docs/guide.md), in order, in a scratch folder."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from daq.setup import parse_setup
from daq.simlab import build_world
from ssid.io import read_frf
from ssid.modal import real_modes

ROOT = Path(__file__).resolve().parents[1]


def guide_commands() -> list[str]:
    text = (ROOT / "docs" / "guide.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```console\n(.*?)```", text, flags=re.S)
    return [ln[2:] for b in blocks for ln in b.splitlines() if ln.startswith("$ ssidlab ")]


def test_guide_has_the_whole_walk_through():
    cmds = " ".join(guide_commands())
    for sub in ("place", "check", "acquire", "identify", "correlate", "discrepancy", "convert",
                "export-model", "bands"):
        assert f"ssidlab {sub} " in cmds


def test_guide_commands_run_as_written(tmp_path):
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for cmd in guide_commands():
        args = cmd.split()[1:]
        p = subprocess.run([sys.executable, "-m", "ssidlab", *args], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, f"{cmd}\n{p.stderr}"
        assert "Traceback" not in p.stderr
    # The guide's claims about what the commands found.
    disc = json.loads((tmp_path / "discrepancy.json").read_text())
    assert disc["effect"] == "added_mass" and disc["dofs"] == ["6+Z"]
    assert disc["gap_after"] < 0.01 * disc["gap_before"]
    # With the mass added the model reproduces the measured FRFs as well as the simulated
    # truth does: its gap is the RMS of the measurement's errors against the truth in units
    # of their stated standard deviations (1.00), which is near 1 (the stated uncertainty is
    # calibrated), and the one effect closes the gap: what a second search finds beyond it
    # (before the floor, a 1e-7 kg oscillator) changes no model FRF value by 0.1 %.
    setup_path = tmp_path / "examples" / "setup_sim.toml"
    setup = parse_setup(setup_path.read_text(), str(setup_path))
    frf = read_frf(tmp_path / "run.h5")
    ref = build_world(setup).frf(frf.freq_hz, outputs=frf.outputs, inputs=frf.inputs)
    ok = frf.valid_mask()
    z_truth = float(np.sqrt(np.mean(np.abs(frf.H - ref.H)[ok] ** 2 / frf.H_var[ok])))
    assert 0.8 < z_truth < 1.2, z_truth
    assert abs(disc["gap_after"] / z_truth - 1) < 0.05, (disc["gap_after"], z_truth)
    assert disc["residual"]["closed"], disc["residual"]["text"]
    seen = disc["residual"]["negligible_effect"]
    assert seen is None or seen["frf_change"] < 1e-3
    assert disc["reactions"]["in_file"] == ["4+Z", "8+Z", "18+Z"] and not disc["reactions"]["applied"]
    # The payload model alone, loaded by the measured reactions, finds the same mass.
    sub = json.loads((tmp_path / "discrepancy_fe.json").read_text())
    assert sub["reactions"]["applied"] and (sub["effect"], sub["dofs"]) == ("added_mass", ["6+Z"])
    assert abs(sub["parameters"]["mass_kg"] - 0.25) < 0.01 and sub["gap_after"] < 1.2
    placement = json.loads((tmp_path / "placement.json").read_text())
    assert {"4+Z", "8+Z", "18+Z"} <= set(placement["chosen"]) and len(placement["chosen"]) == 10
    for name in ("run.h5", "run.uff", "identified.h5", "correlation.json", "updated.h5",
                 "run_copy.uff", "identified.mat", "free.h5", "bands.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    # The free test: as many modes found as the FE substructure has inside the sweep, each
    # paired with its FE mode except the close pair the hidden mass mixes (modes 7 and 8).
    bands = json.loads((tmp_path / "bands.json").read_text())
    assert bands["settings"]["width_hz"] is None
    assert len(bands["modes"]) == len(bands["targets"]["mode_numbers"]) == 9
    paired = [m["target_mode"] for m in bands["modes"] if m.get("target_mode") is not None]
    assert paired == [4, 5, 6, 9, 10, 11, 12]
    unpaired = [m["freq_hz"] for m in bands["modes"] if m.get("target_mode") is None]
    assert len(unpaired) == 2 and all(300 < f < 330 for f in unpaired)
    # Section 3's claim on the same record: identified with `ssidlab identify`, the free test
    # writes a physical M, K (its 1.3-6.2 Hz suspension modes lie below the sweep's 20 Hz, so a
    # near-rigid block fitted from there could carry a negative mass). Step 2 alone reproduced
    # the data to 2.7 %; refined by output error, to 0.030 % (bound 0.1 %), and its undamped
    # frequencies lie within 0.0003 % of the simulated truth's in the band (bound 0.002 %:
    # the roots of step 1 are 0.0007 % off there, the bound leaves room for rounding only).
    p = subprocess.run([sys.executable, "-m", "ssidlab", "identify", "free.h5", "--out", "idfree.h5",
                        "--json", "idfree.json", "--quiet"], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    free = json.loads((tmp_path / "idfree.json").read_text())
    assert free["checks"]["M_min_eig_rel"] > 0 and free["checks"]["K_min_eig_rel"] > 0, free["warnings"]
    assert free["damping_matrix"] == "output_error" and free["checks"]["frf_relative_rms_error"] < 1e-3
    free_setup = ROOT / "examples" / "setup_sim_free.toml"
    M, _, K, dofs = build_world(parse_setup(free_setup.read_text(), str(free_setup))).coupled_model()
    at = [dofs.index(d) for d in free["dofs"]]
    f_true = real_modes(M[np.ix_(at, at)], K[np.ix_(at, at)])[0] / (2 * np.pi)
    f_mk = np.array(free["undamped_freq_hz"])
    lo, hi = free["band_hz"]
    in_band = (f_true >= lo) & (f_true <= hi)
    assert np.abs(f_mk / f_true - 1)[in_band].max() < 2e-5, f_mk
