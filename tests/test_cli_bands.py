"""``ssidlab bands`` run as a user runs it (subprocess, real files), on systems with known
M, C, K whose FRFs are synthesised exactly (noise-free: band processing must find the modes
to the precision of the per-band fits, which are exact on such data)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from ssid.frf import FRFData, accelerance_from_model
from ssid.io import Model, read_model, write_frf, write_model
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system
from ssid.noise import report_noise_frf


def run(*args):
    return subprocess.run([sys.executable, "-m", "ssidlab", "bands", *args], capture_output=True,
                          text=True, timeout=600)


def _root_freq_hz(M, C, K):
    lam, _ = complex_modes(M, C, K)
    return root_frequency_damping(lam)[0] / (2 * np.pi)


def test_bands_finds_every_mode_writes_chart_json_and_modal_model(tmp_path):
    """Every DOF measured (6), all 6 modes (17-540 Hz) in 3-600 Hz: each is found, in at least two bands,
    and the modal model holds them all (its roots are the system's)."""
    M, C, K, dofs = example_system(6, seed=3)
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(3, 600, 400), dofs, [dofs[0], dofs[4]])
    src, js, png, out = (tmp_path / n for n in ("frf.h5", "bands.json", "roots.png", "model.h5"))
    write_frf(str(src), frf)
    p = run(str(src), "--json", str(js), "--plot", str(png), "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    f_true = _root_freq_hz(M, C, K)
    res = json.loads(js.read_text())
    found = np.array([m["freq_hz"] for m in res["modes"]])
    assert found.size == f_true.size and np.allclose(found, f_true, rtol=1e-6)
    assert all(m["n_bands"] >= 2 for m in res["modes"])  # criterion 4
    assert {r["verdict"] for r in res["roots"]} <= {"kept", "outside band", "negative damping",
                                                    "low MPC", "not repeated",
                                                    "same shape as a stronger mode",
                                                    "inside a resolved mode's half-power band",
                                                    "resolved (low-edge band)",
                                                    "resolved (high-edge band)",
                                                    "not repeated by the high-edge band"}
    assert res["settings"]["overlap"] == 0.5 and len(res["bands_hz"]) > 2
    # The low-edge band (3-77.6 Hz, 1.5 widths of 49.75 Hz) follows the layout's bands, the
    # high-edge band (1.5 times the lines of the widest band ending at 600 Hz) comes last; the
    # table names both.
    low, high = res["low_edge_band"], res["high_edge_band"]
    assert low == len(res["bands_hz"]) - 2 and res["bands_hz"][low][0] == 3.0
    assert high == len(res["bands_hz"]) - 1 and res["bands_hz"][high][1] == 600.0
    assert "and a low-edge band (3-" in p.stdout and ", and a high-edge band (" in p.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    model = read_model(str(out))
    assert model.dofs == list(dofs)
    assert np.allclose(res["model"]["natural_freq_hz"], f_true, rtol=1e-6)
    assert np.all(np.linalg.eigvalsh(model.M) > 0)
    assert str(found.size) in p.stdout and f"{f_true[0]:.4f}" in p.stdout
    assert all(r["mpc_applied"] and r["damping_applied"] for r in res["roots"])
    assert "MPC not applied" not in p.stdout


def test_bands_marks_a_mode_kept_without_the_mpc_criterion(tmp_path, payload_10dof_300hz):
    """The payload at 1-300 Hz with the report's noise (seed 2): the 1.29 Hz suspension mode,
    11 half-widths from the nearest line, has a noise-set MPC far below 0.8 and is kept by
    the repeat criterion alone; the table marks its MPC and says why, the JSON says so."""
    frf, f_true = payload_10dof_300hz
    src, js, png = tmp_path / "frf.h5", tmp_path / "bands.json", tmp_path / "roots.png"
    write_frf(str(src), report_noise_frf(frf, seed=2))
    p = run(str(src), "--json", str(js), "--plot", str(png))
    assert p.returncode == 0, p.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not p.stderr
    modes = json.loads(js.read_text())["modes"]
    first = modes[0]
    assert abs(first["freq_hz"] - f_true[0]) < 0.02 * f_true[0]
    assert first["mpc"] < 0.8 and first["mpc_applied"] is False
    assert all(m["mpc_applied"] for m in modes[1:])
    row = next(line for line in p.stdout.splitlines() if line.split()[:1] == ["1"])
    assert f"{first['mpc']:.3f}*" in row
    assert "* MPC not applied" in p.stdout


@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    """8-DOF system (modes 14.5-477 Hz), 4 sensors, 5-520 Hz: 8 modes for a 4-DOF model,
    measured with the report's noise (2 % of each FRF's RMS magnitude and 2 degrees, uniform,
    40 averages; seed 1). Noisy rather than exact data: with 4 of 8 DOFs measured each band's
    4-DOF fit is not exact even without noise, and the bands' noise-level estimates then
    measure that model error, which BP3 takes as noise (docs/algorithm.md, known limits)."""
    M, C, K, dofs = example_system(8, seed=2)
    sensors = [dofs[i] for i in (0, 2, 5, 7)]
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(5, 520, 600), sensors,
                                 [dofs[0], dofs[5]])
    d = tmp_path_factory.mktemp("reduced")
    write_frf(str(d / "frf.h5"), report_noise_frf(frf, seed=1))
    write_model(str(d / "fe.h5"), Model(M=M, K=K, C=C, dofs=list(dofs)))
    return M, C, K, dofs, d


def _layout(res: dict) -> list:
    """The bands the settings laid out: the JSON's bands without the edge bands (last)."""
    edges = [b for b in (res["low_edge_band"], res["high_edge_band"]) if b is not None]
    return res["bands_hz"][: min(edges, default=len(res["bands_hz"]))]


def _all_true(found_hz, f_true, rtol=0.01):
    """Every frequency found is one of the system's within ``rtol`` (the report's 1 % for an
    identified mode; 0.44 % at worst measured in these tests)."""
    found = np.asarray(found_hz)
    return found.size > 0 and np.all(np.min(np.abs(found[:, None] - f_true[None]) / f_true,
                                             axis=1) < rtol)


def test_bands_model_keeps_the_fe_target_modes_first(reduced):
    """With --targets and --target-modes the 4-DOF modal model holds exactly the named modes
    (each within 1 % of its frequency), and the table and JSON name the target each mode
    pairs with; without targets the data choose another set."""
    M, C, K, dofs, d = reduced
    f_true = _root_freq_hz(M, C, K)
    js, out = d / "t.json", d / "t.h5"
    p = run(str(d / "frf.h5"), "--json", str(js), "--out", str(out), "--targets",
            str(d / "fe.h5"), "--target-modes", "1,3-4,7")
    assert p.returncode == 0, p.stderr
    res = json.loads(js.read_text())
    assert res["targets"]["mode_numbers"] == [1, 3, 4, 7]
    held = np.sort(res["model"]["natural_freq_hz"])
    assert np.allclose(held, f_true[[0, 2, 3, 6]], rtol=0.01)
    assert sorted(m["target_mode"] for m in res["modes"] if "target_mode" in m) == [1, 3, 4, 7]
    assert "target (MAC)" in p.stdout
    assert read_model(str(out)).dofs == [dofs[i] for i in (0, 2, 5, 7)]
    # Without targets the data choose (the strongest independent modes): another set here.
    p2 = run(str(d / "frf.h5"), "--json", str(d / "a.json"), "--out", str(d / "a.h5"))
    assert p2.returncode == 0, p2.stderr
    auto = np.sort(json.loads((d / "a.json").read_text())["model"]["natural_freq_hz"])
    assert auto.size == 4 and not np.allclose(auto, held, rtol=0.01) and _all_true(auto, f_true)


def test_bands_settings_change_the_bands(reduced):
    """--width and --overlap set the bands, --solver the per-band fit, --quiet silences the
    table; every mode found is one of the system's."""
    *_, d = reduced
    js = d / "w.json"
    p = run(str(d / "frf.h5"), "--json", str(js), "--width", "100", "--overlap", "0.75",
            "--solver", "ls", "--quiet")
    assert p.returncode == 0, p.stderr
    assert p.stdout == ""
    res = json.loads(js.read_text())
    widths = [hi - lo for lo, hi in _layout(res)]
    assert max(widths) == pytest.approx(100.0)
    assert res["bands_hz"][res["low_edge_band"]] == pytest.approx([5.0, 155.0])  # 1.5 widths
    starts = [lo for lo, _ in _layout(res)][2:5]
    assert np.allclose(np.diff(starts), 25.0)  # 75 % overlap: a step of a quarter width
    assert res["settings"]["solver"] == "ls" and len(res["modes"]) >= 4
    assert _all_true([m["freq_hz"] for m in res["modes"]], _root_freq_hz(*reduced[:3]))


def test_bands_without_enough_modes_for_a_model_keeps_what_it_found(reduced):
    """Below 70 Hz the 8-DOF system has 3 modes, fewer than the 4 sensors: no 4-DOF modal
    model of found modes exists, and ``--no-residual-pair`` refuses to complete one. The run
    says so (status 2, one line), prints the modes it found and keeps them in the JSON."""
    M, C, K, dofs, d = reduced
    f_true = _root_freq_hz(M, C, K)
    assert np.sum(f_true < 70) == 3
    js = d / "few.json"
    p = run(str(d / "frf.h5"), "--json", str(js), "--out", str(d / "few.h5"), "--fmax", "70",
            "--no-residual-pair")
    assert p.returncode == 2 and "no modal model" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    res = json.loads(js.read_text())
    assert "model_error" in res and not (d / "few.h5").exists()
    found = [m["freq_hz"] for m in res["modes"]]
    assert len(found) <= 3 and _all_true(found, f_true)
    table = p.stdout.strip().splitlines()
    assert table[-1].split()[0] == str(len(found)), p.stdout


def test_bands_completes_a_model_one_mode_short_with_a_residual_pair_and_says_so(reduced):
    """Below 70 Hz: 3 modes for 4 sensors. Without ``--no-residual-pair`` the model keeps
    the 3 found and fits its 4th pair above 70 Hz to what they leave of the FRFs: the model
    is written, a warning names the pair, and the JSON records its frequency. The pair lands
    near the system's next mode (78.8 Hz, 1.13 times the edge): measured 81.5 Hz, 3.4 % above
    (noisy record, 4 of 8 DOFs measured, the modes further up in the same residual); the
    bound 5 % tells that mode from the next one (102.6 Hz)."""
    M, C, K, dofs, d = reduced
    f_true = _root_freq_hz(M, C, K)
    js = d / "pair.json"
    p = run(str(d / "frf.h5"), "--json", str(js), "--out", str(d / "pair.h5"), "--fmax", "70",
            "--quiet")
    assert p.returncode == 0, p.stderr
    assert "residual" in p.stderr and "stands for them" in p.stderr
    res = json.loads(js.read_text())
    pair_hz = res["model"]["info"]["bands"]["residual_pair_hz"]
    assert pair_hz == pytest.approx(f_true[3], rel=0.05)
    found = res["model"]["natural_freq_hz"][:3]
    assert _all_true(found, f_true)
    assert (d / "pair.h5").exists()


def _free_beam_run(tmp_path, f_hi_hz: float, *extra: str):
    """``ssidlab bands --out`` on the free-free beam (all 8 DOFs, inputs at both ends) measured
    from 20 Hz to ``f_hi_hz``: (M, K, the process, the JSON, the model file, the source)."""
    from test_rigid_body import free_beam

    M, C, K, dofs = free_beam()
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(20, f_hi_hz, 1200), dofs, ["0+Z", "3+Z"])
    src, js, out = tmp_path / "beam.h5", tmp_path / "beam.json", tmp_path / "model.h5"
    write_frf(str(src), frf)
    p = run(str(src), "--json", str(js), "--out", str(out), "--quiet", *extra)
    return M, K, p, js, out, src


def test_bands_models_a_free_free_beam_with_its_rigid_body_modes(tmp_path):
    """A free-free beam measured from 20 Hz (all 8 DOFs, inputs at both ends): the bands find
    its 6 elastic modes, and the written 8-DOF model takes its two rigid-body modes from the
    mass line below them (a warning says so; the JSON records them); its M and K are the
    beam's (noise-free: measured 3.2e-10 and 1.2e-11, see tests/test_modal_model.py).
    ``--no-rigid-body`` refuses instead."""
    M, K, p, js, out, src = _free_beam_run(tmp_path, 6000.0)
    assert p.returncode == 0, p.stderr
    assert "2 rigid-body mode(s) (free-free structure)" in p.stderr
    res = json.loads(js.read_text())
    assert res["model"]["info"]["bands"]["n_rigid_body_modes"] == 2
    model = read_model(str(out))
    for A, B in ((model.M, M), (model.K, K)):
        assert np.linalg.norm(A - B) / np.linalg.norm(B) < 1e-8
    p = run(str(src), "--json", str(js), "--out", str(tmp_path / "none.h5"), "--no-rigid-body")
    assert p.returncode == 2 and "no modal model" in p.stderr and "6 modes" in p.stderr
    assert not (tmp_path / "none.h5").exists()


def test_bands_models_a_free_beam_short_of_modes_below_and_above_its_band(tmp_path):
    """The same beam measured 20-4500 Hz: 5 elastic modes found, the two rigid-body modes
    below the band and the 4923 Hz mode above it missing. The written 8-DOF model holds
    both, fitted together (both warnings; the JSON records the pair and the rigid-body
    modes), and is the beam's: measured M 6.9e-6, K 3.2e-4 (BP3's error in the found modes,
    see tests/test_modal_model.py); bound 1e-3."""
    M, K, p, js, out, _ = _free_beam_run(tmp_path, 4500.0)
    assert p.returncode == 0, p.stderr
    assert "2 rigid-body mode(s) (free-free structure)" in p.stderr and "last pair" in p.stderr
    bands = json.loads(js.read_text())["model"]["info"]["bands"]
    assert bands["n_rigid_body_modes"] == 2
    assert bands["residual_pair_hz"] == pytest.approx(4922.85, rel=1e-5)
    model = read_model(str(out))
    for A, B in ((model.M, M), (model.K, K)):
        assert np.linalg.norm(A - B) / np.linalg.norm(B) < 1e-3


@pytest.mark.parametrize("extra, message", [
    (["--target-modes", "1,2"], "--target-modes needs --targets"),
    (["--width", "5000"], "wider than the band used"),
    (["--overlap", "1.5"], "between 0 and 1"),
    (["--targets", "FE", "--target-modes", "99"], "has 8 modes"),
    (["--fmin", "600"], "fewer than two frequency lines"),
    (["--target-modes", "2-1", "--targets", "FE"], "the range is reversed (write 1-2)"),
    (["--target-modes", "0-2", "--targets", "FE"], "modes count from 1"),
    # checked with the options, not after the computation (it was an internal error then)
    (["--plot", "roots.txt"], "a chart is written as one of"),
])
def test_bands_bad_input_is_one_line_and_status_2(reduced, extra, message):
    *_, d = reduced
    extra = [str(d / "fe.h5") if a == "FE" else a for a in extra]
    p = run(str(d / "frf.h5"), "--json", str(d / "bad.json"), *extra)
    assert p.returncode == 2, p.stderr
    assert message in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not (d / "bad.json").exists()


def test_bands_refuses_reactions_and_outputs_missing_from_the_fe_model(tmp_path, reduced):
    M, C, K, dofs, d = reduced
    frf = FRFData(freq_hz=np.linspace(5, 520, 50), H=np.ones((50, 2, 1), complex),
                  outputs=dofs[:2], inputs=dofs[:1], H_reaction=np.ones((50, 1, 1), complex),
                  reactions=dofs[1:2])
    write_frf(str(tmp_path / "r.h5"), frf)
    p = run(str(tmp_path / "r.h5"), "--json", str(tmp_path / "r.json"))
    assert p.returncode == 2 and "reactions is not supported" in p.stderr
    write_model(str(tmp_path / "small.h5"), Model(M=M[:2, :2], K=K[:2, :2], C=None, dofs=dofs[:2]))
    p = run(str(d / "frf.h5"), "--json", str(tmp_path / "s.json"), "--targets",
            str(tmp_path / "small.h5"))
    assert p.returncode == 2 and "is not a DOF of the model" in p.stderr


def test_bands_on_a_log_sweep_use_bands_of_equal_line_count(tmp_path, log_sweep_record):
    """A stepped-sine record on a log grid (152 lines, 20-1500 Hz): without --width the bands
    hold equal numbers of lines, the table and the JSON say so, and all 9 modes in the record
    are found; --width still sets one width in Hz."""
    frf, fn = log_sweep_record
    src, js = tmp_path / "sweep.h5", tmp_path / "sweep.json"
    write_frf(str(src), frf)
    p = run(str(src), "--json", str(js), "--solver", "ls")
    assert p.returncode == 0, p.stderr
    res = json.loads(js.read_text())
    assert res["settings"]["width_hz"] is None and res["settings"]["band_lines"] >= 24
    assert p.stdout.splitlines()[0].startswith(
        f"{len(_layout(res))} bands of {res['settings']['band_lines']} lines (uneven line spacing)")
    found = np.array([m["freq_hz"] for m in res["modes"]])
    assert found.size == fn.size and np.allclose(found, fn, rtol=1e-3)
    p = run(str(src), "--json", str(js), "--solver", "ls", "--width", "300", "--quiet")
    assert p.returncode == 0, p.stderr
    res = json.loads(js.read_text())
    assert res["settings"]["width_hz"] == 300.0
    assert max(hi - lo for lo, hi in _layout(res)) == pytest.approx(300.0)


def test_bands_on_a_record_shorter_than_one_default_band(tmp_path):
    """20 lines, fewer than the 24 of a default band: the bands are the record and its halves,
    every mode is still found in two of them, and the table says how wide they really are."""
    M, C, K, dofs = example_system(6, seed=3)
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(3, 600, 20), dofs, [dofs[0], dofs[4]])
    src, js = tmp_path / "short.h5", tmp_path / "short.json"
    write_frf(str(src), frf)
    p = run(str(src), "--json", str(js))
    assert p.returncode == 0, p.stderr
    res = json.loads(js.read_text())
    # The record is the band, with its two part-bands of 10 lines each (the 24-line rule's
    # part-bands would hold 13 and 8).
    assert res["bands_hz"] == [[3.0, 301.5], [3.0, 600.0], [301.5, 600.0]]
    assert res["settings"]["width_hz"] == 597.0 and "3 bands of 597 Hz" in p.stdout
    found = np.array([m["freq_hz"] for m in res["modes"]])
    f_true = _root_freq_hz(M, C, K)
    assert found.size == f_true.size and np.allclose(found, f_true, rtol=1e-6)


def _payload_sweep(f_lo, f_hi, n_lines):
    """The payload's 16 Z DOFs, 2 % damping, shakers at 11+Z and 16+Z, noise-free on a log grid
    (its 79.04 Hz mode in 60-100 Hz)."""
    from ssid.models.payload import Z_DOFS, modal_damping, payload_simulator
    from ssid.tam import guyan_reduce

    p = payload_simulator()
    red = guyan_reduce(p.M, p.K, p.index(Z_DOFS))
    f = f_lo * np.geomspace(1.0, f_hi / f_lo, n_lines)
    return accelerance_from_model(red.M, modal_damping(red.M, red.K, 0.02), red.K, list(Z_DOFS),
                                  f, list(Z_DOFS), ["11+Z", "16+Z"])


def test_bands_on_a_zoom_sweep_confirm_its_mode_or_say_why_none_can_be(tmp_path):
    """A 22-line zoom sweep (fewer lines than one default band): three overlapping bands and its
    mode found. 14 lines (no two bands of the 10 lines step 1 needs): 0 modes, with a warning
    that no root can be confirmed. Bands too narrow for step 1 (--width) are counted as
    skipped in the table and the JSON, not passed off as fitted."""
    src, js = tmp_path / "zoom.h5", tmp_path / "zoom.json"
    write_frf(str(src), _payload_sweep(60.0, 100.0, 22))
    p = run(str(src), "--json", str(js), "--solver", "ls")
    assert p.returncode == 0, p.stderr
    res = json.loads(js.read_text())
    assert len(res["bands_hz"]) == 3 and res["skipped_bands"] == [] and res["warnings"] == []
    assert len(res["modes"]) == 1 and abs(res["modes"][0]["freq_hz"] / 79.0413 - 1) < 1e-4
    assert "1 mode found" in p.stdout and "warning" not in p.stderr

    write_frf(str(src), _payload_sweep(60.0, 100.0, 14))
    p = run(str(src), "--json", str(js), "--solver", "ls")
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("1 band of 14 lines") and "0 modes found" in p.stdout
    assert "warning: no root can be confirmed as a mode" in p.stderr
    assert "criterion 4" in p.stderr and "Traceback" not in p.stderr
    assert json.loads(js.read_text())["warnings"][0].startswith("no root can be confirmed")

    p = run(str(src), "--json", str(js), "--solver", "ls", "--width", "30")
    assert p.returncode == 0, p.stderr
    res = json.loads(js.read_text())
    n_skipped = len([b for b in res["skipped_bands"] if b < len(_layout(res))])
    assert n_skipped >= 1 and res["min_lines"] == 10
    assert f"({n_skipped} skipped: fewer than the 10 lines step 1 needs)" in p.stdout
    assert "no root can be confirmed" in p.stderr


def test_bands_model_states_its_frf_error_and_warns_when_it_misses_the_data(tmp_path):
    """The 6-DOF system at 3 of its DOFs: its 6 modes are found, a 3-DOF model holds 3 and its
    FRFs miss the data by 36 %, which was only in the JSON (checks.frf_relative_rms_error).
    The model line states the error, and a warning says it misses, at the threshold identify
    and pseudo-dof use (5 % and three times the noise); all 6 DOFs measured: no warning."""
    from ssid.fit_checks import MISFIT_FLOOR

    M, C, K, dofs = example_system(6, seed=3)
    f = np.linspace(3, 600, 400)
    for outs, misses in ((dofs[:3], True), (dofs, False)):
        frf = accelerance_from_model(M, C, K, dofs, f, list(outs), [dofs[0]])
        src, js, out = tmp_path / "frf.h5", tmp_path / "b.json", tmp_path / "m.h5"
        write_frf(str(src), frf)
        p = run(str(src), "--json", str(js), "--out", str(out))
        assert p.returncode == 0, p.stderr
        res = json.loads(js.read_text())
        err = res["model"]["checks"]["frf_relative_rms_error"]
        assert (err > MISFIT_FLOOR) == misses, err
        (line,) = [s for s in p.stdout.splitlines() if s.startswith("model:")]
        assert line.endswith(f"; its FRFs differ from the data by {100 * err:.3g} % (relative RMS)")
        said = [w for w in res["warnings"] if "reproduce the measured FRFs only to" in w]
        assert bool(said) == misses and ("warning: the written M, C, K" in p.stderr) == misses
        if misses:
            assert "it holds 3 of the 6 modes found" in said[0]
