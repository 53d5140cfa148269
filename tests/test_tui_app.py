"""The lab-run TUI (issue 8) driven headless through Textual's Pilot at 80x24: load a setup,
run a short simulated test to identified modes, abort a run mid-way."""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import signal
import time
from pathlib import Path

import h5py
import pytest

pytest.importorskip("textual")

from textual.widgets import Button, DataTable, Input, Static, Switch, TabbedContent

from ssid.io import read_frf
from tui.app import LabApp
from tui.cli import add_tui_subcommand
from tui.session import Acquisition, ProgressParser, run_file_state

from test_daq_helpers import all_safe

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "setup_sim.toml"
SIZE = (80, 24)


def small_setup(tmp_path: Path, n_lines: int = 30) -> Path:
    """examples/setup_sim.toml with few lines and no refinement (a few seconds simulated)."""
    text = EXAMPLE.read_text(encoding="utf-8")
    out = []
    for line in text.splitlines():
        if line.startswith("n_lines ="):
            line = f"n_lines = {n_lines}"
        elif line.startswith("refine ="):
            line = "refine = 1"
        elif line.startswith("uff ="):
            continue
        out.append(line)
    path = tmp_path / "small.toml"
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


async def wait_for(pilot, cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            # The run's own log tells where a stalled run stopped (CI stalls went unexplained
            # twice): ask a run still going for its threads' stacks (ssidlab acquire prints
            # them on SIGUSR1) and give its output a moment to reach the log.
            acq = getattr(pilot.app, "acquisition", None)
            if acq is not None and acq.running:
                try:
                    os.kill(acq.proc.pid, signal.SIGUSR1)
                    await pilot.pause(2.0)
                except OSError:
                    pass
            try:
                tail = "\n".join(log_text(pilot.app).splitlines()[-120:])
            except Exception as exc:  # noqa: BLE001 -- the timeout is the failure; the log is extra
                tail = f"(no log: {exc})"
            raise AssertionError(f"timed out after {timeout} s waiting for {what}; the TUI log ends:\n{tail}")
        await pilot.pause(0.05)


def log_text(app: LabApp) -> str:
    return "\n".join(strip.text for strip in app.query_one("#log").lines)


def test_load_example_setup_and_bad_file(tmp_path):
    async def go():
        app = LabApp()
        async with app.run_test(size=SIZE) as pilot:
            inp = app.query_one("#setup-path", Input)
            inp.value = str(EXAMPLE)
            await pilot.press("enter")
            assert app.setup is not None
            assert app.query_one("#channels", DataTable).row_count == 21
            exc = str(app.query_one("#excitation", Static).render())
            assert "stepped sine 20-1500 Hz" in exc and "2 shakers" in exc
            assert str(app.query_one("#setup-error", Static).render()) == ""
            assert app.query_one("#out-path", Input).value == "run.h5"
            assert app.query_one("#sim", Switch).value is True
            # A broken file: one line, the table emptied.
            bad = tmp_path / "bad.toml"
            bad.write_text(EXAMPLE.read_text().replace("n_lines = 40", "n_linez = 40"))
            inp.value = str(bad)
            await pilot.press("ctrl+l")
            err = str(app.query_one("#setup-error", Static).render())
            assert err.startswith("error: ") and "n_linez" in err and "\n" not in err
            assert app.setup is None and app.query_one("#channels", DataTable).row_count == 0
            inp.value = str(tmp_path / "missing.toml")
            await pilot.press("enter")
            assert str(app.query_one("#setup-error", Static).render()).startswith("error: ")
            # Keyboard tab switching.
            assert inp.has_focus  # function keys switch tabs even while typing
            await pilot.press("f3")
            assert app.query_one(TabbedContent).active == "results"
            await pilot.press("f2")
            assert app.query_one(TabbedContent).active == "run"
            await pilot.press("f1")
            assert app.query_one(TabbedContent).active == "setup"

    asyncio.run(go())


def test_simulated_run_to_identified_modes(tmp_path):
    setup = small_setup(tmp_path)
    out = tmp_path / "run.h5"

    async def go():
        app = LabApp(str(setup), out=str(out), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            assert app.setup is not None
            await pilot.press("f5")
            assert app.query_one(TabbedContent).active == "run"
            await wait_for(pilot, lambda: app.outcome is not None, 40, "the run to end")
            assert app.outcome.complete, log_text(app)
            await wait_for(pilot, lambda: bool(app.results_message), 60, "identification")
            assert app.results is not None, app.results_message
            modes = app.results.modes
            assert app.query_one(TabbedContent).active == "results"
            table = app.query_one("#modes", DataTable)
            assert table.row_count == len(modes) >= 3
            freqs = [m.freq_hz for m in modes]
            # What identify_mck returns, shown as is (its accuracy is tested in ssid's tests).
            assert freqs == sorted(freqs) and all(f > 0 for f in freqs)
            assert all(math.isfinite(m.damping_ratio) for m in modes)
            first = table.get_row_at(0)
            assert first[0].rstrip("*") == "1" and float(first[1]) == pytest.approx(freqs[0], abs=5e-3)
            assert any(m.in_band for m in modes)
            marks = [table.get_row_at(i)[0].endswith("*") for i in range(table.row_count)]
            assert marks == [not m.in_band for m in modes]
            # MAC against the simulated lab's nominal model and the discrepancy finding: the
            # example hides 0.25 kg at 6+Z (examples/setup_sim.toml [[sim.effects]]).
            assert app.query_one("#mac", DataTable).row_count == len(app.results.pairs) >= 3
            assert all(0.0 <= p["mac"] <= 1.0 for p in app.results.pairs)
            d = app.results.discrepancy
            assert d is not None and d["gap_after"] < d["gap_before"], app.results.notes
            assert "gap" in str(app.query_one("#discrepancy", Static).render())
            # Exports, by key, next to the run file.
            for key, name in (("h", "run_ssid_model.h5"), ("u", "run.uff"), ("p", "run_frf_11_Z_11_Z.png")):
                await pilot.press(key)
                assert (tmp_path / name).is_file(), str(app.query_one("#export-status", Static).render())
            from ssid.io import read_model

            assert read_model(tmp_path / "run_ssid_model.h5").n == len(read_frf(out).outputs)
            assert app.query_one("#progress").progress == pytest.approx(1.0)
            text = log_text(app)
            assert "simulated lab started" in text and "run complete" in text
        assert not app.acquisition.running

    asyncio.run(go())
    assert run_file_state(out) == "complete"
    assert read_frf(out).n_in == 2


def test_abort_mid_run_stops_safely_and_keeps_the_file(tmp_path):
    setup = small_setup(tmp_path, n_lines=40)
    out = tmp_path / "cut.h5"

    async def go():
        app = LabApp(str(setup), out=str(out), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f5")
            # Abort once the first line has been measured (deterministic: a file with data).
            await wait_for(pilot, lambda: "sub-lines" in log_text(app), 30, "a first measured line")
            await pilot.press("f8")
            await wait_for(pilot, lambda: app.outcome is not None, 30, "the run to stop")
            assert app.outcome.aborted and app.outcome.returncode == 130, log_text(app)
            assert app.outcome.state == "interrupted"
            status = str(app.query_one("#run-status", Static).render())
            assert "aborted" in status and "interrupted" in status
            assert "F5 resumes" in str(app.query_one("#results-status", Static).render())
            assert app.results is None and app.query_one("#modes", DataTable).row_count == 0
        assert not app.acquisition.running

    asyncio.run(go())
    frf = read_frf(out)  # the contract's FRF datasets are readable after the abort
    assert frf.n_in == 2 and frf.n_freq == 40
    assert run_file_state(out) == "interrupted"
    with h5py.File(out, "r") as f:  # the measured sub-lines were kept (resumable), not all done
        n_done = int(f["acq/n_done"][0])
    assert 0 < n_done < 2 * frf.n_freq


def test_sim_switch_sets_the_command(tmp_path):
    async def go():
        app = LabApp(str(EXAMPLE), out=str(tmp_path / "r.h5"))
        async with app.run_test(size=SIZE) as pilot:
            sw = app.query_one("#sim", Switch)
            sw.focus()
            await pilot.press("space")
            assert sw.value is False and "off" in str(app.query_one("#sim-state", Static).render())
            await pilot.press("space")
            assert sw.value is True and "--sim" in str(app.query_one("#sim-state", Static).render())

    asyncio.run(go())
    assert Acquisition("s.toml", "r.h5", sim=True).argv[-1] == "--sim"
    assert "--sim" not in Acquisition("s.toml", "r.h5", sim=False).argv
    assert Acquisition("s.toml", "r.h5").argv[1:6] == ["-m", "ssidlab", "acquire", "s.toml", "--out"]


def test_progress_parser():
    p = ProgressParser("stepped_sine", 20.0, 2000.0, 2)
    assert p.feed("simulated lab started") is None
    assert p.feed("  shaker 0    20.000 Hz  drive 0.2 Vpp") == pytest.approx(0.0)
    assert p.feed("  shaker 0   200.000 Hz  drive 0.2 Vpp") == pytest.approx(0.25)
    assert p.feed("  shaker 1  2000.000 Hz  drive 0.2 Vpp") == pytest.approx(1.0)
    assert p.feed("  shaker 0    20.000 Hz  drive 0.2 Vpp") == pytest.approx(1.0)  # never back
    r = ProgressParser("random", 10.0, 100.0, 1)
    assert r.feed("  average 4/16  min coherence 0.99") == pytest.approx(0.25)


def test_cli_subcommand():
    parser = argparse.ArgumentParser(prog="ssidlab")
    sub = parser.add_subparsers(dest="command")
    p = add_tui_subcommand(sub)
    assert p.prog == "ssidlab tui"
    args = parser.parse_args(["tui", "s.toml", "--out", "r.h5", "--no-sim"])
    assert (args.setup, args.out, args.sim) == ("s.toml", "r.h5", False) and callable(args.run)
    args = parser.parse_args(["tui"])
    assert args.setup is None and args.sim is True


def test_quit_mid_run_stops_the_subprocess(tmp_path):
    setup = small_setup(tmp_path, n_lines=40)
    out = tmp_path / "quit.h5"

    async def go():
        app = LabApp(str(setup), out=str(out), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f5")
            await wait_for(pilot, lambda: "sub-lines" in log_text(app), 30, "a first measured line")
            proc = app.acquisition.proc
            await pilot.press("ctrl+q")
        return proc

    proc = asyncio.run(go())
    assert proc.poll() == 130  # reaped, stopped by SIGINT (safe), not killed
    assert run_file_state(out) == "interrupted"


def lab_setup(tmp_path: Path, n_lines: int):
    """The small setup pointed at a simulated lab running in this test process, reached as
    real hardware is (sim switch off): SCPI over TCP, Modbus TCP, CAN FD through the lab's
    TCP gateway. The test reads the simulated instruments' state directly."""
    from daq.setup import load_setup
    from daq.simlab import build_world
    from sim_devices.lab import SimLab

    path = small_setup(tmp_path, n_lines=n_lines)
    setup = load_setup(path)
    lab = SimLab(build_world(setup), generator_transport="tcp", gateway=True).start()
    ep = lab.endpoints()
    text = path.read_text(encoding="utf-8")
    text = text.replace('url = "/dev/ttyUSB0"', f'url = "{ep["generators"][0]}"')
    # amplifier j feeds shaker j in the example; the lab serves one amplifier per shaker
    for j, old in enumerate(('host = "192.168.0.10"', 'host = "192.168.0.11"')):
        a = ep["amplifiers"][j]
        text = text.replace(f"{old}\nport = 502", f'host = "{a["host"]}"\nport = {a["port"]}')
    text = text.replace('interface = "socketcan"', 'interface = "tcp"').replace(
        'channel = "can0"', f'channel = "{ep["daq"]["gateway"]}"')
    hw = tmp_path / "lab.toml"
    hw.write_text(text, encoding="utf-8")
    assert "192.168" not in text and "socketcan" not in text
    return lab, hw


def sub_lines(app: LabApp) -> int:
    return sum(len(v) for v in app.live.sub_lines.values()) if app.live else 0


@pytest.mark.serial  # the simulated lab in its own process, on the amplifier's 1 s watchdog
def test_lab_hardware_pause_resume_abort_then_resume_from_the_ui(tmp_path):
    """With the switch off the TUI runs the setup's own instruments. Pause leaves the
    generator off and the amplifiers disabled until resume; abort mid-run leaves them so for
    good; F5 on the unfinished run file resumes it to the end and its results."""
    lab, hw = lab_setup(tmp_path, n_lines=30)
    world = lab.world
    out = tmp_path / "lab.h5"

    async def go():
        app = LabApp(str(hw), out=str(out), sim=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f4")  # connection check: every instrument answers, nothing driven
            await wait_for(pilot, lambda: "answered" in str(app.query_one("#check-status", Static).render()),
                           20, "the instrument check")
            inst = app.query_one("#instruments", DataTable)
            rows = [inst.get_row_at(i) for i in range(inst.row_count)]
            assert [r[0] for r in rows] == ["gen0", "amp0", "amp1", "daq"]
            assert all(r[3].startswith("ok") for r in rows), rows
            assert "SIM-33522" in rows[0][4]
            await pilot.press("f5")
            await wait_for(pilot, lambda: sub_lines(app) >= 2, 40, "two measured lines")
            assert not all_safe(world)  # it is driving
            await pilot.press("f6")
            await wait_for(pilot, lambda: app.live.paused, 30, "the pause")
            n_paused = sub_lines(app)
            assert all_safe(world)  # read from the simulated instruments themselves
            assert "PAUSED" in str(app.query_one("#run-status", Static).render())
            assert "PAUSED" in str(app.query_one("#inst-status", Static).render())
            assert not app.query_one("#resume", Button).disabled and app.query_one("#pause", Button).disabled
            await pilot.pause(1.0)
            assert sub_lines(app) == n_paused and all_safe(world)  # it stays paused
            await pilot.press("f7")
            await wait_for(pilot, lambda: sub_lines(app) >= n_paused + 2, 40, "lines after the resume")
            await pilot.press("f8")
            await wait_for(pilot, lambda: app.outcome is not None, 30, "the run to stop")
            assert app.outcome.aborted and app.outcome.state == "interrupted", log_text(app)
            assert all_safe(world)
            # Resume from the UI: F5 continues the unfinished file.
            await pilot.press("f5")
            await wait_for(pilot, lambda: bool(app.results_message), 120, "the resumed run and its results")
            assert app.outcome.complete, log_text(app)
            assert "resuming" in log_text(app)
            assert app.results is not None and app.results.modes, app.results_message
            # Real hardware, no model file given: modes only, and the tab says how to get MAC.
            assert app.results.pairs == [] and "model file" in str(app.query_one("#results-status", Static).render())
        assert not app.acquisition.running

    try:
        asyncio.run(go())
        assert all_safe(world)
    finally:
        lab.stop()
    assert run_file_state(out) == "complete"
    with h5py.File(out, "r") as f:
        assert int(f["acq/n_done"][0]) == 2 * 30  # every sub-line once: none lost, none doubled


def test_new_setup_from_the_example(tmp_path):
    """Ctrl+N writes the example setup to the path given (never over an existing file) and
    loads it; what it writes is the simulated lab's example, examples/setup_sim.toml."""
    target = tmp_path / "mine.toml"

    async def go():
        app = LabApp()
        async with app.run_test(size=SIZE) as pilot:
            app.query_one("#setup-path", Input).value = str(target)
            await pilot.press("ctrl+n")
            assert target.is_file() and app.setup is not None
            assert app.query_one("#channels", DataTable).row_count == 21
            await pilot.press("ctrl+n")  # again: the file exists now, it is left alone
            assert "not overwritten" in str(app.query_one("#setup-error", Static).render())

    asyncio.run(go())
    assert target.read_text(encoding="utf-8") == EXAMPLE.read_text(encoding="utf-8")


@pytest.mark.serial  # the simulated lab in its own process, on the amplifier's 1 s watchdog
def test_end_of_input_stops_a_controlled_run_safely(tmp_path):
    """What happens when the TUI dies however it dies: the run's stdin reaches end of input,
    and ``ssidlab acquire --control-stdin`` stops safely - read on the instruments."""
    import subprocess
    import sys

    lab, hw = lab_setup(tmp_path, n_lines=30)
    out = tmp_path / "orphan.h5"
    try:
        proc = subprocess.Popen([sys.executable, "-m", "ssidlab", "acquire", str(hw), "--out", str(out),
                                 "--events", "--control-stdin"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
        try:
            n = 0
            for line in proc.stdout:
                n += line.startswith('@event {"event":"sub_line"')
                if n == 2:
                    break
            assert n == 2 and not all_safe(lab.world)  # it is driving
            proc.stdin.close()  # the controlling program is gone
            proc.stdout.read()
            assert proc.wait(60) == 130
        finally:
            if proc.poll() is None:
                proc.kill()
        assert all_safe(lab.world)
    finally:
        lab.stop()
    assert run_file_state(out) == "interrupted"


async def press_until_stopped(pilot, app: LabApp, key: str, fault: str) -> str:
    """Press ``key`` (F5, Ctrl+R) and wait for the run to stop on ``fault`` (exit 3, the words
    in its run file state); returns the status line."""
    await pilot.press(key)
    await wait_for(pilot, lambda: app.outcome is not None, 60, "the run to stop")
    assert app.outcome.returncode == 3 and fault in app.outcome.state, log_text(app)
    return str(app.query_one("#run-status", Static).render())


async def press_until_complete(pilot, app: LabApp, key: str) -> None:
    """Press ``key`` on a stopped run and wait for it to run to the end."""
    await pilot.press(key)
    await wait_for(pilot, lambda: app.outcome is not None and app.outcome.returncode != 3, 120, "the resumed run")
    assert app.outcome.complete, log_text(app)


def test_a_range_too_small_stops_the_run_and_f5_resumes_with_the_edited_range(tmp_path):
    """Periodic random at 4 Vpp with acc 3+Z on a 0.1 V range: the run stops on the DAQ
    overload, and the status says to raise that range in the setup file before F5; with the
    file edited, F5 resumes the run to the end."""
    from test_daq_helpers import random_setup

    acc3 = 'name = "acc 3+Z"\ninput = 2\ndof = "3+Z"\nquantity = "acceleration"\nsensitivity_mv_per_unit = 10.0\n'
    text = random_setup(averages=4).replace("drive_vpp = 0.5", "drive_vpp = 4.0")
    assert acc3 in text and "drive_vpp = 4.0" in text
    setup = tmp_path / "random.toml"
    setup.write_text(text.replace(acc3, acc3 + "range_volt = 0.1\n"), encoding="utf-8")
    out = tmp_path / "random.h5"

    async def go():
        app = LabApp(str(setup), out=str(out), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            status = await press_until_stopped(pilot, app, "f5", "DAQ overload")
            assert f"raise its range_volt in {setup}" in status, status
            setup.write_text(text.replace(acc3, acc3 + "range_volt = 1.0\n"), encoding="utf-8")
            await press_until_complete(pilot, app, "f5")
            assert "DAQ input ranges changed for this session: 'acc 3+Z' 0.1 -> 1 V" in log_text(app)
        assert not app.acquisition.running

    asyncio.run(go())
    assert run_file_state(out) == "complete"
    assert read_frf(out).n_avg == 4


@pytest.mark.serial  # the simulated lab in its own process, on the amplifier's 1 s watchdog
def test_an_instrument_not_reached_stops_the_run_and_f5_resumes_at_its_new_address(tmp_path):
    """Lab hardware (switch off) whose generator does not answer where the setup says: the
    run stops, and the status says to put the instrument's new address in the setup file
    before F5; with the lab answering elsewhere and the file edited, F5 resumes the run to
    the end."""
    lab, hw = lab_setup(tmp_path, n_lines=8)
    lab.stop()  # nothing listens at the addresses in lab.toml any more
    out = tmp_path / "moved.h5"

    async def go():
        app = LabApp(str(hw), out=str(out), sim=False)
        async with app.run_test(size=SIZE) as pilot:
            status = await press_until_stopped(pilot, app, "f5", "(link down)")
            assert f"if it answers at another address now, put that in {hw} first" in status, status
            moved, again = lab_setup(tmp_path, n_lines=8)  # the lab back on other ports; lab.toml edited
            assert again == hw
            try:
                await press_until_complete(pilot, app, "f5")
                assert "setup changed for this session: [[generators]] 'gen0' url" in log_text(app)
            finally:
                moved.stop()
            assert all_safe(moved.world)
        assert not app.acquisition.running

    asyncio.run(go())
    assert run_file_state(out) == "complete"


@pytest.mark.serial  # the simulated lab in its own process, on the amplifier's 1 s watchdog
def test_a_replaced_generator_stops_f5_and_ctrl_r_resumes_with_it(tmp_path):
    """An aborted lab-hardware run; the lab comes back with another generator serial (a
    replaced unit). F5 stops before driving, and the status offers Ctrl+R, which resumes
    with --new-instruments to the end. Ctrl+R on a new run file starts nothing."""
    lab, hw = lab_setup(tmp_path, n_lines=8)
    out = tmp_path / "replaced.h5"

    async def go():
        app = LabApp(str(hw), out=str(out), sim=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("ctrl+r")
            assert app.acquisition is None  # nothing to resume yet
            await pilot.press("f5")
            await wait_for(pilot, lambda: sub_lines(app) >= 2, 60, "two sub-lines")
            await pilot.press("f8")
            await wait_for(pilot, lambda: app.outcome is not None, 60, "the abort")
            lab.stop()
            moved, again = lab_setup(tmp_path, n_lines=8)
            assert again == hw
            try:
                moved.generators[0].serial = "SN04711"
                status = await press_until_stopped(pilot, app, "f5", "not the instruments of the run's last session")
                assert "Ctrl+R resumes with the instruments that answer now" in status, status
                assert all_safe(moved.world)
                await press_until_complete(pilot, app, "ctrl+r")
                assert "--new-instruments" in log_text(app)
                assert "instruments replaced since the last session: gen0" in log_text(app)
            finally:
                moved.stop()
            assert all_safe(moved.world)

    try:
        asyncio.run(go())
    finally:
        lab.stop()
    assert run_file_state(out) == "complete"


@pytest.mark.serial  # the simulated lab in its own process, on the amplifier's 1 s watchdog
def test_an_amplifier_trip_stops_the_run_and_ctrl_f_resets_it_for_f5(tmp_path):
    """Lab hardware whose door is opened mid-run: amp0 trips and the run stops; the status
    says to reset the latched fault once its cause is gone. With the door closed, Ctrl+F
    resets it (from the Run tab; the Setup tab shows the check, nothing switched on) and F5
    resumes the run to the end."""
    lab, hw = lab_setup(tmp_path, n_lines=8)
    out = tmp_path / "tripped.h5"
    amp = lab.amplifiers[0]

    async def go():
        app = LabApp(str(hw), out=str(out), sim=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f5")
            await wait_for(pilot, lambda: sub_lines(app) >= 2, 60, "two sub-lines")
            amp.set_interlock(False)
            await wait_for(pilot, lambda: app.outcome is not None, 60, "the trip to stop the run")
            assert app.outcome.returncode == 3 and "amplifier interlock open" in app.outcome.state
            status = str(app.query_one("#run-status", Static).render())
            assert "Ctrl+F resets it first" in status, status
            amp.set_interlock(True)
            await pilot.press("ctrl+f")
            await wait_for(pilot, lambda: "answered" in str(app.query_one("#check-status", Static).render()), 30,
                           "the check")
            assert app.query_one(TabbedContent).active == "setup"
            assert str(app.query_one("#check-status", Static).render()) == "instruments: all 4 answered and ready"
            assert amp.model.fault_code == 0 and not amp.model.enabled
            await press_until_complete(pilot, app, "f5")
        assert not app.acquisition.running

    try:
        asyncio.run(go())
    finally:
        lab.stop()
    assert run_file_state(out) == "complete"
