"""Interrupted stepped-sine runs on the simulated lab: Ctrl-C, kill -9 and a SIGINT the
shell would have ignored leave a readable file whose resume gives the uninterrupted run's
FRFs; a stop by a fault says how to continue; older run files resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from daq.run import run_test
from daq.setup import parse_setup
from ssid.io import read_frf

from test_daq_helpers import cli, ctrl_c_at_line, run_on_sim, sine_setup

ROOT = Path(__file__).resolve().parents[1]


def _same_frf(a, b, rtol=2 * 2e-3):
    """Lines measured in different sessions are independent estimates, each within the
    setup's ``accuracy`` (2e-3, sine_setup) of the truth: they may differ by twice that."""
    assert np.array_equal(a.freq_hz, b.freq_hz)
    assert np.array_equal(a.valid_mask(), b.valid_mask())
    ok = a.valid_mask()
    assert np.max(np.abs(a.H[ok] - b.H[ok]) / np.abs(b.H[ok])) < rtol


def test_ctrl_c_leaves_a_readable_file_and_resume_gives_the_same_frf(tmp_path):
    setup = parse_setup(sine_setup(two=True), str(tmp_path / "s.toml"))
    run_on_sim(setup, tmp_path / "full.h5")
    with pytest.raises(KeyboardInterrupt):
        run_on_sim(setup, tmp_path / "cut.h5", echo=ctrl_c_at_line(12))
    part = read_frf(tmp_path / "cut.h5")  # readable mid-run: every completed line, rest invalid
    with h5py.File(tmp_path / "cut.h5") as f:
        assert f["acq"].attrs["state"] == "interrupted" and 5 <= f["acq/n_done"][0] <= 12
    assert part.valid_mask().sum() < read_frf(tmp_path / "full.h5").valid_mask().sum()
    summary = run_test(setup, out=str(tmp_path / "cut.h5"), resume=True, sim=True, echo=lambda m: None)
    assert summary["state"] == "complete"
    _same_frf(read_frf(tmp_path / "cut.h5"), read_frf(tmp_path / "full.h5"))
    # Resuming with a different setup file is refused (hash check).
    other = tmp_path / "other.toml"
    other.write_text(setup.text.replace("force_n = 1.0", "force_n = 1.5"))
    status, err = cli(["--resume", str(tmp_path / "full.h5"), str(other), "--sim"])
    assert status == 2 and "differs from the setup" in err


def _signal_at_sub_lines(proc: subprocess.Popen, signals: dict[int, int | list[int]], timeout_s: float) -> None:
    """Send ``signals[n]`` (one signal or a list, sent in turn) to the acquiring ``proc`` at its
    ``n``-th sub-line progress line, for each ``n``, and after the last one wait for it to end
    (killed if it has not within ``timeout_s``)."""
    try:
        k = 0
        for line in proc.stdout:
            k += line.startswith("  shaker")
            if line.startswith("  shaker") and k in signals:
                for sig in signals[k] if isinstance(signals[k], list) else [signals[k]]:
                    proc.send_signal(sig)
                    time.sleep(0.02)
                if k == max(signals):
                    break
        proc.wait(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()


def _acquire_sim(tmp_path: Path, **popen_kw) -> subprocess.Popen:
    """`ssidlab acquire s.toml --sim --out run.h5` in ``tmp_path`` (two shakers, stepped
    sine), stdout and stderr piped."""
    (tmp_path / "s.toml").write_text(sine_setup(two=True))
    return subprocess.Popen(
        [sys.executable, "-u", "-m", "ssidlab", "acquire", str(tmp_path / "s.toml"), "--sim",
         "--out", str(tmp_path / "run.h5")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        env=dict(os.environ, PYTHONPATH=str(ROOT)), **popen_kw)


def test_kill_9_mid_run_then_resume_gives_the_same_file(tmp_path):
    """A separate process runs `ssidlab acquire --sim` and is killed with SIGKILL mid-run."""
    text = sine_setup(two=True)
    (tmp_path / "s.toml").write_text(text)
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    code = ("import sys; sys.path.insert(0, %r); sys.path.insert(0, %r); from test_daq_helpers import cli; "
            "sys.exit(cli(sys.argv[1:])[0])" % (str(ROOT), str(ROOT / "tests")))
    proc = subprocess.Popen([sys.executable, "-u", "-c", code, str(tmp_path / "s.toml"), "--sim",
                             "--out", str(tmp_path / "killed.h5")], stdout=subprocess.PIPE, text=True,
                            cwd=tmp_path)
    _signal_at_sub_lines(proc, {9: signal.SIGKILL}, timeout_s=30)
    assert proc.returncode == -signal.SIGKILL
    part = read_frf(tmp_path / "killed.h5")  # the killed run's file opens and validates
    with h5py.File(tmp_path / "killed.h5") as f:
        assert f["acq"].attrs["state"] == "running" and f["acq/n_done"][0] >= 8
    assert part.n_freq > 0
    status, _ = cli(["--resume", str(tmp_path / "killed.h5"), "--sim", "--quiet"])
    assert status == 0
    run_on_sim(setup, tmp_path / "full.h5")
    _same_frf(read_frf(tmp_path / "killed.h5"), read_frf(tmp_path / "full.h5"))


def test_a_reader_of_the_output_gone_stops_the_run_and_stderr_says_how_to_continue(tmp_path):
    """`ssidlab acquire ... | head`: the reader of stdout goes away mid-run. The run stops as
    a Unix tool does on SIGPIPE (exit 141), instruments safe and file resumable, and stderr,
    which still works, says so and how to continue (it said nothing, and the file's state
    was "failed: BrokenPipeError")."""
    proc = _acquire_sim(tmp_path)
    k = 0
    for line in proc.stdout:
        k += line.startswith("  shaker")
        if k == 3:
            break
    proc.stdout.close()  # the reader goes away
    try:
        err = proc.stderr.read()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 141, err
    assert "ssidlab acquire: stopped: the reader of the output went away (broken pipe)" in err, err
    assert f"continue with: ssidlab acquire --resume {tmp_path / 'run.h5'} --sim" in err, err
    with h5py.File(tmp_path / "run.h5") as f:
        assert f["acq"].attrs["state"] == "stopped: the output's reader went away (broken pipe)"
        assert f["acq/n_done"][0] >= 3


def test_sigint_stops_a_run_started_with_sigint_ignored(tmp_path):
    """A run started in the background by a non-interactive shell inherits SIGINT as ignored;
    Ctrl-C (or the TUI's abort) must still stop it safely, not be lost while the drive runs."""
    proc = _acquire_sim(tmp_path, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        _signal_at_sub_lines(proc, {1: signal.SIGINT}, timeout_s=60)
    finally:
        err = proc.stderr.read()
        proc.stderr.close()
    assert proc.returncode == 130, err
    with h5py.File(tmp_path / "run.h5") as f:
        assert f["acq"].attrs["state"] == "interrupted"
        n_done = int(f["acq/n_done"][0])
    assert f"{n_done} measurement records are kept in" in err and n_done > 0, err
    assert f"continue with: ssidlab acquire --resume {tmp_path / 'run.h5'} --sim" in err, err


def test_a_run_stopped_by_a_fault_says_how_to_continue(tmp_path):
    """Without --sim the setup's generator is at a loopback port where nothing listens: the
    run stops before its first line (exit 3), and stderr names the instrument, the file, the
    command that continues the run, and how to continue it with the instrument's address
    where it answers now."""
    text = sine_setup()
    assert 'url = "socket://127.0.0.1:1"' in text
    (tmp_path / "s.toml").write_text(text)
    out = tmp_path / "run one.h5"
    p = subprocess.run([sys.executable, "-m", "ssidlab", "acquire", str(tmp_path / "s.toml"), "--out", str(out)],
                       capture_output=True, text=True, cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 3 and len(lines) == 3, p.stderr
    assert lines[0].startswith("ssidlab acquire: stopped: run stopped safely: instrument lost (link down): gen0:"), lines[0]
    assert lines[1].startswith("ssidlab acquire: nothing was measured yet; the setup is kept in"), lines[1]
    assert lines[1].endswith(f"continue with: ssidlab acquire --resume '{out}'")  # quoted for the shell
    assert lines[2].startswith("ssidlab acquire: if the instrument answers at another address now"), lines[2]
    assert lines[2].endswith(f"continue with it: ssidlab acquire --resume '{out}' {tmp_path / 's.toml'}"), lines[2]
    with h5py.File(out) as f:
        assert f["acq"].attrs["state"].startswith("stopped: instrument lost")


def test_an_interrupt_after_the_run_was_complete_says_so(tmp_path, capsys):
    """A Ctrl-C held back while the run finished is raised once its file is complete: the
    command then says so (not "records kept, continue with") and that a resume does the
    steps cut after it (the UFF export; test_daq_sine.test_uff58_export)."""
    from ssidlab.cli_acquire import _say_how_to_continue

    setup = parse_setup(sine_setup(n_lines=3, refine=2), str(tmp_path / "s.toml"))
    run_on_sim(setup, tmp_path / "run.h5")
    capsys.readouterr()
    said = _say_how_to_continue(tmp_path / "run.h5", sim=True)
    err = capsys.readouterr().err
    with h5py.File(tmp_path / "run.h5") as f:
        n_records = int(f["acq/n_done"][0])
    assert f"the run file was complete ({n_records} measurement records" in err, err
    assert f"done by: ssidlab acquire --resume {tmp_path / 'run.h5'} --sim" in err
    assert "kept" not in err and said["state"] == "complete" and said["remedy"] is None


def test_a_run_file_from_before_the_transient_shape_resumes(tmp_path):
    """Run files written before ``X_transient`` was kept: resuming one adds the field with
    NaN for the rows already there, and their variance falls back to the relative transient
    times each amplitude (what those files' lines were measured with)."""
    from daq.stepped_sine import _variance_with_transient
    from daq.storage import RunFile

    rf = RunFile.create(tmp_path / "r.h5", kind="stepped_sine", setup_text="", setup_sha256="",
                        freq_hz=np.array([10.0]), outputs=["1+Z"], inputs=["1+Z"], reactions=[],
                        channel_names=["force", "acc"], meta={}, attrs={})
    old = {"grid_index": 0, "pattern": 0, "freq_hz": 10.0, "status": 0, "transient": 0.01,
           "X": np.array([2.0, 3.0 + 4.0j]), "X_var": np.array([1e-6, 2e-6])}
    rf.append_record(old)
    rf.commit(1)
    del rf.acq["records/X_transient"]  # as the older files were written
    new = dict(old, X_transient=np.array([0.0, 0.2]))
    rf.append_record(new)
    rf.commit(2)
    rec = rf.records()
    assert np.isnan(rec["X_transient"][0]).all() and np.array_equal(rec["X_transient"][1], [0.0, 0.2])
    row0 = {k: v[0] for k, v in rec.items()}
    np.testing.assert_allclose(_variance_with_transient(row0), [1e-6 + 0.02**2, 2e-6 + 0.05**2])
    np.testing.assert_allclose(_variance_with_transient(new), [1e-6, 2e-6 + 0.04])
    rf.f.close()


def test_sigusr1_prints_every_threads_stack_and_the_run_goes_on(tmp_path):
    """`kill -USR1` on a running `ssidlab acquire` prints its threads' stacks to stderr (where
    a run that does not stop is waiting) and does not stop or disturb the run: it measures
    on until the Ctrl-C two sub-lines later, then stops safely as usual. Twenty in a row: the
    stacks were dumped by faulthandler's C-level handler, which reads the other threads' frames
    while they run; one such dump crashed the run in CI (a segfault, exit -11), and twenty did
    on 3 of 6 tries."""
    proc = _acquire_sim(tmp_path)
    # Twenty dumps overfill a pipe nobody reads, and the run would wait on its stderr.
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(proc.stderr.read()), daemon=True)
    reader.start()
    try:
        _signal_at_sub_lines(proc, {1: [signal.SIGUSR1] * 20, 3: signal.SIGINT}, timeout_s=60)
    finally:
        reader.join(timeout=30)
        err = "".join(got)
        proc.stderr.close()
    assert "most recent call first" in err and "Thread 0x" in err, err
    assert proc.returncode == 130, err
    # The main thread's stack is the run's, as it was when the signal came.
    assert "Current thread 0x" in err and " in run_test" in err, err
    with h5py.File(tmp_path / "run.h5") as f:
        assert f["acq"].attrs["state"] == "interrupted" and int(f["acq/n_done"][0]) >= 3


def test_a_stalled_safe_state_reports_where_it_waits(tmp_path):
    """Reaching the safe state is timed: past its limit every thread's stack goes to stderr
    once and the wait goes on; a block that ends in time prints nothing."""
    code = ("import time; from daq.run import _stall_report\n"
            "with _stall_report(0.3):\n    time.sleep(1.0)\n"
            "print('after', flush=True)\n"
            "with _stall_report(5.0):\n    time.sleep(0.1)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == 0 and p.stdout == "after\n", p.stderr
    assert p.stderr.count("most recent call first") >= 1 and "line 3" in p.stderr, p.stderr
    assert p.stderr.count("the safe state is not reached after 0.3 s") == 1, p.stderr
