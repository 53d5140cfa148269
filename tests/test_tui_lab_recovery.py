"""The lab-run TUI against a simulated lab reached as real hardware is (issue 8): pause,
resume and abort leave the excitation off, and each stop the run can recover from (a range
too small, an instrument not reached or replaced, an amplifier trip, the end of input) says
what to do and resumes from the UI."""

from __future__ import annotations

import asyncio
from pathlib import Path

import h5py
import pytest

pytest.importorskip("textual")

from test_daq_helpers import all_safe
from textual.widgets import Button, DataTable, Static, TabbedContent
from tui_helpers import SIZE, log_text, small_setup, wait_for

from ssid.io import read_frf
from tui.app import LabApp
from tui.session import run_file_state


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
