"""The edges of a run: a kill or a Ctrl-C while its file is being finished, a control input
that is already at its end, a damaged run file, a simulated run resumed without ``--sim``,
and a Ctrl-C before the command has finished importing."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_daq_helpers import cli, ctrl_c_at_line, killed_at_write, random_setup, run_on_sim, sine_setup

from daq.setup import parse_setup
from ssid.errors import InputError
from ssid.io import read_frf

ROOT = Path(__file__).resolve().parents[1]


def _state(path: Path) -> str:
    with h5py.File(path, "r") as f:
        return str(f["acq"].attrs["state"])


def test_kill_9_while_the_file_is_finished_leaves_a_run_that_resume_finishes(tmp_path):
    """The process dies after the compact file is written and before it replaces the run
    file. The run file on disk must still be a running one, which a resume makes compact;
    it was marked complete first, so the resume found nothing to do and the file kept the
    running layout (every grid line, the unmeasured ones NaN) and the half-written copy."""
    text = sine_setup(n_lines=3, refine=2)
    (tmp_path / "s.toml").write_text(text)
    code = ("import os, signal, sys; sys.path[:0] = [%r, %r]\n"
            "import daq.run_file_replace as rfr\n"
            "write_frf = rfr.write_frf\n"
            "def then_killed(path, frf):\n"
            "    write_frf(path, frf)\n"
            "    os.kill(os.getpid(), signal.SIGKILL)\n"
            "rfr.write_frf = then_killed\n"
            "from test_daq_helpers import cli\n"
            "sys.exit(cli(sys.argv[1:])[0])\n" % (str(ROOT), str(ROOT / "tests")))
    run = tmp_path / "run.h5"
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path / "s.toml"), "--sim", "--out", str(run), "--quiet"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert p.returncode == -signal.SIGKILL, p.stderr
    assert list(tmp_path.glob(".run.h5.*.final"))  # killed between the two files
    assert _state(run) == "running"
    status, _ = cli(["--resume", str(run), "--sim", "--quiet"])
    assert status == 0 and _state(run) == "complete"
    assert not list(tmp_path.glob(".run.h5.*.final"))
    run_on_sim(parse_setup(text, str(tmp_path / "s.toml")), tmp_path / "full.h5")
    resumed, uninterrupted = read_frf(run), read_frf(tmp_path / "full.h5")
    assert np.array_equal(resumed.freq_hz, uninterrupted.freq_hz)  # compact: measured lines only
    assert resumed.valid_mask().all()


def test_a_finished_file_that_does_not_read_back_does_not_replace_the_run_file(tmp_path, monkeypatch):
    """On a full disk HDF5 reports the compact file's failed writes at its close, where h5py
    only prints them: the broken copy replaced the run file, and the measurement was lost.
    Here the compact FRF is written short (its H cut to one line) as such a write would leave
    it; the run stops with the run file kept, and a resume finishes it."""
    import daq.run_file_replace as rfr
    from ssid.io import write_frf

    def written_short(path, frf):
        write_frf(path, frf)
        with h5py.File(path, "r+") as f:  # what a failed write leaves: a dataset cut short
            H = f["H"][:1]
            del f["H"]
            f["H"] = H

    monkeypatch.setattr(rfr, "write_frf", written_short)
    text = sine_setup(n_lines=3, refine=2)
    (tmp_path / "s.toml").write_text(text)
    run = tmp_path / "run.h5"
    with pytest.raises(OSError, match=f"{run}: the finished file did not read back whole .*the run file is kept"):
        cli([str(tmp_path / "s.toml"), "--sim", "--out", str(run), "--quiet"])  # exit 2 in ssidlab.cli.main
    assert _state(run) == "running" and not list(tmp_path.glob(".run.h5.*.final"))
    monkeypatch.undo()
    status, err = cli(["--resume", str(run), "--sim", "--quiet"])
    assert status == 0 and _state(run) == "complete", err
    assert read_frf(run).valid_mask().all()


def test_a_ctrl_c_while_the_finished_run_reaches_its_safe_state_is_not_lost(tmp_path, monkeypatch):
    """Held back while the file is finished (it must not cut the safe state or the file),
    the Ctrl-C is raised once the file is complete: the steps after it (the UFF export) are
    cut, as the operator asked. It used to be dropped and the command went on to exit 0."""
    from daq.storage import RunFile

    finalize = RunFile.finalize

    def ctrl_c_then_finalize(self, *args, **kw):
        os.kill(os.getpid(), signal.SIGINT)
        return finalize(self, *args, **kw)

    monkeypatch.setattr(RunFile, "finalize", ctrl_c_then_finalize)
    setup = parse_setup(sine_setup(n_lines=3, refine=2).replace('file = "run.h5"', 'file = "run.h5"\nuff = "run.uff"'),
                        str(tmp_path / "s.toml"))
    with pytest.raises(KeyboardInterrupt):
        run_on_sim(setup, tmp_path / "run.h5")
    assert _state(tmp_path / "run.h5") == "complete"
    assert not (tmp_path / "run.uff").exists()


def test_end_of_control_input_before_the_run_starts_is_an_interrupt_like_any_other(tmp_path):
    """``--control-stdin`` with its input already at the end (``< /dev/null``): the abort
    came before the command's handler was in place and ended with a bare "interrupted"."""
    (tmp_path / "s.toml").write_text(sine_setup())
    p = subprocess.run([sys.executable, "-m", "ssidlab", "acquire", str(tmp_path / "s.toml"), "--sim",
                        "--out", str(tmp_path / "run.h5"), "--control-stdin"], stdin=subprocess.DEVNULL,
                       capture_output=True, text=True, cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       timeout=120)
    assert p.returncode == 130, p.stderr
    assert "ssidlab acquire: interrupted (outputs off, amplifiers disabled)" in p.stderr, p.stderr


def _interrupted_run(tmp_path: Path) -> Path:
    """A stepped-sine run on the simulated lab (``--sim``) stopped by Ctrl-C at its 6th line."""
    from daq.run import run_test

    setup = parse_setup(sine_setup(), str(tmp_path / "s.toml"))
    out = tmp_path / "run.h5"
    with pytest.raises(KeyboardInterrupt):
        run_test(setup, out=str(out), sim=True, echo=ctrl_c_at_line(6))
    assert _state(out) == "interrupted"
    return out


def test_a_damaged_run_file_is_refused_before_any_instrument_is_touched(tmp_path):
    """A run file whose second half is zeros (a disk error, a copy cut short) opened, and
    HDF5 reported the damage only when the resume replayed its records: after the
    amplifiers were enabled, as a message that did not name the file, and the file's state
    was overwritten."""
    out = _interrupted_run(tmp_path)
    data = bytearray(out.read_bytes())
    half = len(data) // 2
    data[half:] = bytes(len(data) - half)
    out.write_bytes(bytes(data))
    status, err = cli(["--resume", str(out), "--sim", "--quiet"])
    assert status == 2 and err.startswith(f"{out}: the run file is damaged and cannot be resumed"), err
    assert out.read_bytes() == bytes(data)  # not written to


def test_a_resume_leaves_the_compact_file_of_a_run_still_finishing(tmp_path):
    """A resume opened the run file in the moment between another run's closing it and
    renaming its compact file over it, and deleted that file as a killed finalize's leftover:
    the finishing run then failed ("No such file or directory", QA). Only the leftovers of
    processes that are gone are deleted."""
    out = _interrupted_run(tmp_path)
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    try:
        finishing = tmp_path / f".run.h5.{alive.pid}.final"
        leftover = tmp_path / f".run.h5.{int(gone.stdout)}.final"
        finishing.write_bytes(b"being renamed")
        leftover.write_bytes(b"half written")
        status, err = cli(["--resume", str(out), "--sim", "--quiet"])
        assert status == 0, err
        assert finishing.read_bytes() == b"being renamed" and not leftover.exists()
    finally:
        alive.kill()
        alive.wait()


def _meta_not_an_object(f: h5py.File) -> None:
    del f["acq/meta_json"]
    f["acq"].create_dataset("meta_json", data="[1, 2]", dtype=h5py.string_dtype())


def _set(name: str, index, value):
    def change(f: h5py.File) -> None:
        f[name][index] = value
    return change


@pytest.mark.parametrize("change, what", [
    (_set("acq/n_done", 0, 500), "/acq/n_done is 500, but the records hold"),
    (lambda f: f["acq/records"].__delitem__("thd"), "record field 'thd' is missing"),
    (_set("acq/records/X", (3, 0), np.nan), "a kept record's 'X' is not finite"),
    (_set("acq/records/freq_hz", 2, -1.0), "a kept record's 'freq_hz' is not finite or out of range"),
    (_meta_not_an_object, "/acq/meta_json is not a JSON object"),
])
def test_a_run_file_that_contradicts_how_it_is_written_is_refused(tmp_path, change, what):
    """Files HDF5 reads without complaint but that no crash leaves (another program wrote
    into them): the resume drove the shakers and then stopped on an internal error
    (KeyError, ValueError), or with n_done past the records appended after 450 empty rows."""
    out = _interrupted_run(tmp_path)
    with h5py.File(out, "r+") as f:
        change(f)
    before = out.read_bytes()
    status, err = cli(["--resume", str(out), "--sim", "--quiet"])
    assert status == 2 and err.startswith(f"{out}: the run file is damaged and cannot be resumed ({what}"), err
    assert out.read_bytes() == before


def test_a_simulated_run_resumed_without_sim_is_told_to_add_it(tmp_path):
    """Without ``--sim`` the resume went for the setup's placeholder addresses, stopped with
    "instrument lost (link down)" and advised a new address."""
    out = _interrupted_run(tmp_path)
    before = out.read_bytes()
    status, err = cli(["--resume", str(out), "--quiet"])
    assert status == 2 and err == f"{out}: the run was measured on the simulated lab; resume it with --sim", err
    assert out.read_bytes() == before
    status, _ = cli(["--resume", str(out), "--sim", "--quiet"])
    assert status == 0 and _state(out) == "complete"


def test_a_ctrl_c_while_the_command_imports_is_one_line_not_a_traceback(monkeypatch, capsys):
    """The console command's first second goes to importing numpy, scipy and h5py: a
    Ctrl-C then raised inside an import, before ``ssidlab.cli.main`` could catch it."""
    import importlib.abc

    import ssidlab.cli  # noqa: F401 -- imported, so that it can be taken out below
    from ssidlab.__main__ import entry

    class CtrlCOnImport(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name == "ssidlab.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "ssidlab.cli")
    monkeypatch.setattr(sys, "meta_path", [CtrlCOnImport(), *sys.meta_path])
    assert entry() == 130
    assert capsys.readouterr().err == "ssidlab: interrupted\n"


def test_a_run_that_kept_nothing_is_not_a_success(tmp_path, capsys):
    """Every line aborted by a limit no drive keeps: the schedule ran to its end and the
    command said "complete" with exit 0 (nothing on stderr under --quiet), leaving a file
    every analysis refuses."""
    (tmp_path / "s.toml").write_text(sine_setup(n_lines=3, refine=1, limits="max_accel_m_per_s2 = 1e-6"))
    status, _ = cli([str(tmp_path / "s.toml"), "--sim", "--out", str(tmp_path / "run.h5"), "--quiet"])
    err = capsys.readouterr().err
    assert status == 2, err
    assert (f"ssidlab acquire: error: {tmp_path / 'run.h5'}: the run is complete but measured nothing usable: "
            "every FRF value is blanked (every sub-line aborted by a limit)") in err, err
    assert _state(tmp_path / "run.h5") == "complete"  # what was measured is kept, as always


def _setup_with_uff(tmp_path: Path, uff: str) -> Path:
    setup = tmp_path / "s.toml"
    setup.write_text(sine_setup(n_lines=3, refine=2).replace('file = "run.h5"', f'file = "run.h5"\nuff = "{uff}"'))
    return setup


@pytest.mark.parametrize("uff, argv, what", [
    (None, ["--out", "{d}/run.h5", "--json", "{d}/run.h5"], "{d}/run.h5: given for two different outputs"),
    ("run.h5", [], "run.h5: the UFF export ([output] uff) would overwrite the run file; give one of them "
                   "another name"),
    ("x.uff", ["--out", "{d}/clash.uff"], "{d}/clash.uff: the UFF export ([output] uff) would overwrite the run "
                                          "file; give one of them another name"),
    ("{d}/s.toml", [], "{d}/s.toml: the UFF export ([output] uff) would overwrite the setup file; give one of them "
                       "another name"),
])
def test_an_output_that_would_overwrite_the_run_file_or_the_setup_is_refused_before_the_run(
        tmp_path, monkeypatch, uff, argv, what):
    """The summary (--json) or the UFF export named like the run file replaced the
    measurement with a JSON or UFF copy at the run's end (exit 0, "/acq" gone), and an export
    named like the setup overwrote the setup; only --resume's file was checked."""
    monkeypatch.chdir(tmp_path)
    setup = _setup_with_uff(tmp_path, (uff or "x.uff").format(d=tmp_path))
    text = setup.read_text()
    status, err = cli([str(setup), "--sim", "--quiet", *(a.format(d=tmp_path) for a in argv)])
    assert status == 2 and err == what.format(d=tmp_path), err
    assert not list(tmp_path.glob("*.h5")) and not list(tmp_path.glob("*.uff"))  # nothing driven
    assert setup.read_text() == text


def test_a_run_file_created_by_another_run_meanwhile_is_not_truncated(tmp_path, monkeypatch):
    """Two runs into one file: the second passed the "exists already" check before the first
    created the file, then opened it with mode "w", which truncated the first run's file before
    HDF5's lock refused it (the first run's records became zeros, its setup text empty)."""
    from daq.storage import RunFile

    out = tmp_path / "run.h5"
    out.write_bytes(b"the other run's file")
    monkeypatch.setattr(Path, "exists", lambda self: False if self == out else os.path.exists(self))
    with pytest.raises(InputError, match="exists already"):
        RunFile.create(out, kind="stepped_sine", setup_text="", setup_sha256="", freq_hz=np.ones(2),
                       outputs=["1+Z"], inputs=["1+Z"], reactions=[], channel_names=["a"], meta={}, attrs={})
    assert out.read_bytes() == b"the other run's file"


def _kill_at_write(run: Path, nth_write: int, args: list[str], cwd: Path) -> None:
    """``ssidlab acquire ARGS``, killed (-9) at its ``nth_write`` write to ``run`` (strace
    fault injection)."""
    killed = subprocess.run(
        [*killed_at_write(run, nth_write), sys.executable, "-m", "ssidlab", "acquire", *args, "--sim", "--quiet"],
        cwd=cwd, capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert killed.returncode != 0 and run.exists(), killed.stderr
    assert _state(run) == "running"  # killed mid-run, not after it


def test_a_run_file_is_created_on_a_file_system_without_hard_links(tmp_path, monkeypatch):
    """The new file is built under another name and linked to its own; where the file system
    refuses links (EPERM, as some network and FAT mounts do) it is renamed instead."""
    import errno

    from daq.storage import RunFile

    def no_links(src, dst):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    out = tmp_path / "run.h5"
    kw = dict(kind="stepped_sine", setup_text="", setup_sha256="", freq_hz=np.ones(2), outputs=["1+Z"],
              inputs=["1+Z"], reactions=[], channel_names=["a"], meta={}, attrs={})
    RunFile.create(out, **kw).close()
    assert [p.name for p in tmp_path.iterdir()] == ["run.h5"] and _state(out) == "running"
    with pytest.raises(InputError, match="exists already"):
        RunFile.create(out, **kw)


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace to kill the run inside a write")
@pytest.mark.parametrize("nth_write", [20, 47, 100, 200, 300])
def test_a_run_killed_inside_a_lines_flush_can_be_resumed(tmp_path, nth_write):
    """kill -9 at the nth write to the run file, then resume. HDF5 wrote a line's commit
    counter to disk before the records' new extent within one flush: killed between the two,
    the file held a counter past its records and the resume refused it as damaged (on this
    setup at every 20th write from the 80th, one per line). Inside the first line's flush
    (writes 41-59 here, and 20) HDF5 built the records' chunk index and linked the noise
    floor's group into /acq: killed there, the file was damaged."""
    setup = tmp_path / "s.toml"
    setup.write_text(sine_setup(two=True))
    run = tmp_path / "run.h5"
    _kill_at_write(run, nth_write, [str(setup), "--out", str(run)], tmp_path)
    status, err = cli(["--resume", str(run), "--sim", "--quiet"])
    assert status == 0, err
    assert _state(run) == "complete" and read_frf(run).valid_mask().all()


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace to kill the run inside a write")
@pytest.mark.parametrize("nth_write", [60, 66, 72])
def test_a_random_run_killed_inside_an_averages_flush_keeps_its_averages(tmp_path, nth_write):
    """A random run overwrote its one set of spectral sums in place at every average: a kill
    -9 inside the flush left sums of different averages and a count ahead of the commit
    counter, and the resume started again from no averages (on this setup at writes 49-59
    and 64-74, inside the 2nd and 3rd averages' flushes). Two sets, written in turn, keep the
    last committed one whole."""
    setup = tmp_path / "r.toml"
    setup.write_text(random_setup(averages=8))
    run = tmp_path / "run.h5"
    _kill_at_write(run, nth_write, [str(setup), "--out", str(run)], tmp_path)
    with h5py.File(run, "r") as f:
        committed = int(f["acq/n_done"][0])
    resumed = subprocess.run([sys.executable, "-m", "ssidlab", "acquire", "--resume", str(run), "--sim"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=180,
                             env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert resumed.returncode == 0, resumed.stderr
    if committed:
        assert f"resuming: {committed} averages on file" in resumed.stdout, resumed.stdout
    assert _state(run) == "complete" and read_frf(run).n_avg == 8


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace to kill the run inside a write")
def test_a_resume_killed_while_it_writes_its_session_keeps_the_run(tmp_path):
    """A resume replaces the run's metadata (``/acq/meta_json``); HDF5 did it in place, and a
    kill -9 inside (the resume's 27th write here) left /acq unreadable: the records of the
    lines committed before could no longer be resumed or read. It is now done in a copy of
    the file, renamed over it when whole."""
    setup = tmp_path / "s.toml"
    setup.write_text(sine_setup(two=True))
    run = tmp_path / "run.h5"
    _kill_at_write(run, 200, [str(setup), "--out", str(run)], tmp_path)
    with h5py.File(run, "r") as f:
        committed = int(f["acq/n_done"][0])
    assert committed > 0
    _kill_at_write(run, 27, ["--resume", str(run)], tmp_path)
    status, err = cli(["--resume", str(run), "--sim", "--quiet"])
    assert status == 0, err
    assert _state(run) == "complete" and read_frf(run).valid_mask().all()
    with h5py.File(run, "r") as f:
        assert f["acq/records/grid_index"].shape[0] >= committed
