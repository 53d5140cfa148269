"""What the commands do, as docs/formats.md, docs/acquisition.md and docs/drivers.md say: an
interrupt, where warnings go, what a refusal still writes, how a bad option is named."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import DOFS, chain_model, reap
from test_daq_helpers import sine_setup

from ssid.frf import accelerance_from_model
from ssid.io import write_frf, write_model

REPO_ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
    env.pop("SSIDLAB_DEBUG", None)
    return env


def _ssidlab(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ssidlab", *map(str, args)], cwd=cwd, env=_env(),
                          capture_output=True, text=True, timeout=120)


def test_sim_lab_stopped_by_ctrl_c_ends_as_an_interrupted_command(tmp_path):
    """SIGINT, how sim-lab normally ends, gave status 0 and no message, where the exit-status
    table promises 130 and "ssidlab <subcommand>: interrupted" for every command."""
    proc = subprocess.Popen([sys.executable, "-m", "ssidlab", "sim-lab", "--speed", "0", "--no-noise"],
                            cwd=tmp_path, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "generators" in json.loads(proc.stdout.readline())  # started: its handler is in place
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 130
        assert proc.stderr.read() == "ssidlab sim-lab: interrupted\n"
    finally:
        reap(proc)
    # Its --duration run out is a success.
    p = _ssidlab("sim-lab", "--speed", "0", "--duration", "0.1", cwd=tmp_path)
    assert (p.returncode, p.stderr) == (0, "")


def test_acquire_warns_of_a_skipped_uff_export_on_stderr_also_when_quiet(tmp_path):
    """The warning went to stdout with the progress lines, and --quiet dropped it: the UFF
    file the setup asked for was missing without a word."""
    text = sine_setup(n_lines=2, refine=1, limits="max_accel_m_per_s2 = 1e-4")
    (tmp_path / "s.toml").write_text(text.replace('file = "run.h5"', 'file = "run.h5"\nuff = "run.uff"'))
    p = _ssidlab("acquire", "s.toml", "--sim", "--quiet", cwd=tmp_path)
    assert p.returncode == 2, p.stderr  # every line aborted by the limit: nothing to export
    assert p.stdout == ""
    assert p.stderr.startswith("warning: UFF export skipped: run.uff: no FRF has two valid lines"), p.stderr
    assert not (tmp_path / "run.uff").exists()


def test_discrepancy_and_correlate_warnings_go_to_stderr_also_when_quiet(tmp_path, ssidlab):
    """Their warnings were lines of the stdout summary, and --quiet dropped them ("check the
    transducers' calibration", "no test modes to correlate")."""
    from ssid.discrepancy.cases import make_case

    case = make_case(1000, structure="chain", effect="added_mass")
    write_model(tmp_path / "nominal.h5", case.nominal)
    write_frf(tmp_path / "frf.h5", case.frf)
    # A floor above any change: no effect is named, and the channel gains explain the data.
    status, out, err = ssidlab("discrepancy", "--model", tmp_path / "nominal.h5", "--measured", tmp_path / "frf.h5",
                               "--json", tmp_path / "d.json", "--negligible", "1e6", "--quiet")
    said = json.loads((tmp_path / "d.json").read_text())["warnings"]
    assert status == 0 and out == "" and said
    assert err.splitlines() == [f"warning: {w}" for w in said]
    status, out, _ = ssidlab("discrepancy", "--model", tmp_path / "nominal.h5", "--measured", tmp_path / "frf.h5",
                             "--json", tmp_path / "d2.json", "--negligible", "1e6")
    assert status == 0 and out and "warning" not in out

    m = chain_model()
    write_model(tmp_path / "chain.h5", m)
    write_frf(tmp_path / "chain_frf.h5", accelerance_from_model(m.M, m.C, m.K, DOFS, np.linspace(2.0, 60.0, 64),
                                                                DOFS, ["1+Z", "3+Z"]))
    status, out, err = ssidlab("correlate", "--model", tmp_path / "chain.h5", "--frf", tmp_path / "chain_frf.h5",
                               "--fmin", "2", "--fmax", "4", "--json", tmp_path / "c.json", "--quiet")
    assert status == 0 and out == ""
    assert "warning: no CMIF peak in the measured FRFs: no test modes to correlate\n" in err


def test_pseudo_dof_without_a_model_still_writes_the_plot_of_its_roots(tmp_path):
    """With --out and no model to be made, RESULT.json was written and STAB.png was not,
    though the same command without --out writes it: the roots exist either way."""
    m = chain_model()
    # One mode in the band for three sensors: too few for a 3-DOF model.
    write_frf(tmp_path / "frf.h5", accelerance_from_model(m.M, m.C, m.K, DOFS, np.linspace(2.0, 12.0, 200),
                                                          DOFS, ["1+Z"]))
    p = _ssidlab("pseudo-dof", "frf.h5", "--out", "m.h5", "--plot", "stab.png", "--json", "r.json", cwd=tmp_path)
    assert p.returncode == 2
    assert p.stderr.startswith("ssidlab pseudo-dof: error: frf.h5: no model (") and p.stderr.count("\n") == 1
    assert p.stderr.endswith("; the roots are in r.json and stab.png\n"), p.stderr
    assert (tmp_path / "stab.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((tmp_path / "r.json").read_text())["roots"]
    assert not (tmp_path / "m.h5").exists()


def test_an_unknown_option_before_the_command_is_named(ssidlab):
    """"ssidlab --bogus" said that COMMAND was missing, not what was wrong."""
    assert ssidlab("--bogus") == (2, "", "ssidlab: error: unrecognized arguments: --bogus\n")
    assert ssidlab() == (2, "", "ssidlab: error: the following arguments are required: COMMAND\n")


def test_example_demo_says_the_example_stands_in_for_the_simulated_lab(tmp_path):
    """It said "simulated lab not built yet", as if there were none."""
    from ssidlab.demo import run_demo

    class FirstLine(Exception):
        pass

    def echo(line: str) -> None:
        raise FirstLine(line)  # the first line is all this test needs

    with pytest.raises(FirstLine) as said:
        run_demo(str(tmp_path), echo=echo)
    assert str(said.value).startswith("[1/4] synthesising the bundled example instead of running the simulated lab")


def test_lab_demo_lists_summary_json_among_its_files(tmp_path):
    """The final "done ...:" line and summary.json's "files" are made before summary.json is
    written, and left it out."""
    from ssidlab.lab_demo import _files_written

    (tmp_path / "frf.h5").touch()
    assert _files_written(tmp_path) == ["frf.h5", "summary.json"]
