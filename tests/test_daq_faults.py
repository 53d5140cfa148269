"""Every instrument fault mid-run stops the run safely and says why; the file stays readable
and resumable; the simulated instruments end with all outputs off and amplifiers disabled."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from daq.resume import load_resume_setup
from daq.run import run_test
from daq.safety import MAX_OVER_RANGE_IN_ROW, RunStopped
from daq.setup import load_setup, parse_setup
from daq.simlab import build_world, start_sim_lab
from ssid.io import read_frf

from test_daq_helpers import all_safe, cli, frf_error, pointed_at, random_setup, sine_setup

FAULTS = {
    "interlock": (lambda lab: lab.amplifiers[0].set_interlock(False), "interlock open"),
    "over_temperature": (lambda lab: lab.amplifiers[0].inject_over_temperature(), "amplifier fault"),
    "heartbeat": (lambda lab: lab.amplifiers[0].inject("heartbeat_stall"), "heartbeat lost"),
    # a sensor stuck beyond its range (one clipped sample only re-reads a sine line, below)
    "overload": (lambda lab: lab.daq.inject("rail", channel=1), "DAQ overload"),
    "frame_gap": (lambda lab: lab.daq.inject("drop", channel=2, seq=1), "frame"),
    "bus_off": (lambda lab: lab.daq.inject("bus_off", duration_s=2.5), "bus-off"),
    "generator_lost": (lambda lab: lab.generators[0].inject("silent", count=2), "instrument lost"),
}


def stopped_run(tmp_path, inject, n_lines: int = 6, text: str | None = None) -> tuple[str, bool]:
    """A run on the simulated lab (``text``: its setup, a stepped sine by default) with
    ``inject(lab)`` called at its third progress line: the RunStopped message, and whether
    every simulated drive was off before the lab stopped."""
    setup = parse_setup(text or sine_setup(n_lines=n_lines, refine=2), str(tmp_path / "s.toml"))
    handle, inst = start_sim_lab(setup)
    seen = []

    def echo(msg):
        seen.append(msg)
        if len(seen) == 3:
            inject(handle.lab)

    try:
        with pytest.raises(RunStopped) as e:
            run_test(inst, out=str(tmp_path / "run.h5"), echo=echo)
        safe = all_safe(handle.world)
    finally:
        handle.stop()
    return str(e.value), safe


@pytest.mark.parametrize("fault", list(FAULTS))
def test_fault_mid_run_ends_in_the_safe_state(tmp_path, fault):
    inject, words = FAULTS[fault]
    # a stalled heartbeat shows only after 1 s
    msg, safe = stopped_run(tmp_path, inject, n_lines=16 if fault == "heartbeat" else 6)
    assert safe, f"not safe after {fault}"
    assert words in msg and msg.startswith("run stopped safely") and "\n" not in msg
    if fault == "overload":  # each line's drive halved ten times, then aborted; three stop the run
        assert f"on {MAX_OVER_RANGE_IN_ROW} sub-lines in a row" in msg
    with h5py.File(tmp_path / "run.h5") as f:
        state = f["acq"].attrs["state"]
        assert state.startswith("stopped:") and words in state
        assert f["acq/n_done"][0] >= 2
    assert read_frf(tmp_path / "run.h5").n_freq > 0  # every completed line is on file


def test_a_clipped_sample_costs_a_sine_line_a_reading_not_the_run(tmp_path):
    """One sample over range on the force gauge mid-run: the line's drive goes down by
    ``compression`` and the line is read again, at its level in the end. It stopped the run
    (a resume met the same clip again when the level, not a spike, caused it)."""
    setup = parse_setup(sine_setup(n_lines=6, refine=2), str(tmp_path / "s.toml"))
    handle, inst = start_sim_lab(setup)
    seen = []

    def echo(msg):
        seen.append(msg)
        if len(seen) == 3:
            handle.lab.daq.inject("overload", channel=0)

    try:
        summary = run_test(inst, out=str(tmp_path / "run.h5"), echo=echo)
        safe = all_safe(handle.world)
        # noise-free: each line within the accuracy asked (2e-3; a clean run's worst is 8.7e-4)
        worst = float(np.nanmax(frf_error(read_frf(tmp_path / "run.h5"), handle.world)))
    finally:
        handle.stop()
    assert safe and summary["state"] == "complete" and summary["n_aborted"] == 0
    assert summary["n_level_off"] == 0  # every line at its level, the re-read one too
    assert worst < setup.sine.accuracy, worst
    with h5py.File(tmp_path / "run.h5") as f:
        assert np.all(f["acq/records/status"][()] == 0)


def test_an_amplifier_gone_silent_is_not_called_safe(tmp_path):
    """The amplifier's Modbus server stops mid-run. The run stops, but the driver cannot
    confirm that amplifier disabled (a real one's comms watchdog would do it within 1 s), so
    the message leads with the unconfirmed safe state instead of "stopped safely"."""
    msg, _ = stopped_run(tmp_path, lambda lab: lab.amplifiers[0].stop())
    assert msg.startswith("safe state NOT confirmed (check the instruments): amp0:"), msg
    assert "the run ended as: stopped: instrument lost" in msg and "\n" not in msg
    with h5py.File(tmp_path / "run.h5") as f:
        state = f["acq"].attrs["state"]
        assert state.startswith("stopped: instrument lost") and "safe state not confirmed: amp0:" in state
    assert read_frf(tmp_path / "run.h5").n_freq > 0  # the lines measured before are kept


@pytest.mark.parametrize("fault", ["interlock", "overload", "bus_off", "generator_lost"])
def test_fault_mid_random_run_ends_in_the_safe_state(tmp_path, fault):
    """The same faults during periodic random (the arbitrary waveform playing, periods read
    one at a time while the steady state is checked): safe, said, and the averages before
    kept."""
    inject, words = FAULTS[fault]
    msg, safe = stopped_run(tmp_path, inject, text=random_setup(averages=12))
    assert safe, f"not safe after {fault}"
    assert words in msg and msg.startswith("run stopped safely") and "\n" not in msg
    if fault == "overload":
        assert f"on {MAX_OVER_RANGE_IN_ROW} averages in a row" in msg
    with h5py.File(tmp_path / "run.h5") as f:
        assert f["acq"].attrs["state"].startswith("stopped:") and f["acq/n_done"][0] >= 3
    assert read_frf(tmp_path / "run.h5").n_avg >= 3


@pytest.mark.parametrize("kind", ["periodic", "random"])
def test_a_clipped_sample_costs_a_random_run_an_average_not_the_run(tmp_path, kind):
    """One sample over range on the force gauge mid-run: the average it fell in is rejected
    and measured again (periodic: the same realisation; continuous: a new record, the
    blocks before the clip kept), so the run ends with every average it asked for and FRFs
    as good as a clean run's. It stopped the run."""
    errors = {}
    for spike in (False, True):
        setup = parse_setup(random_setup(kind=kind, averages=8), str(tmp_path / f"s{spike}.toml"))
        handle, inst = start_sim_lab(setup)
        seen = []

        def echo(msg):
            seen.append(msg)
            if spike and len(seen) == 1:
                handle.lab.daq.inject("overload", channel=0)

        try:
            summary = run_test(inst, out=str(tmp_path / f"run{spike}.h5"), echo=echo)
            safe = all_safe(handle.world)
            # the median: a continuous record's worst line (leakage at a resonance) is its own
            errors[spike] = float(np.nanmedian(frf_error(read_frf(tmp_path / f"run{spike}.h5"), handle.world)))
        finally:
            handle.stop()
        assert safe and summary["state"] == "complete" and summary["n_avg"] == 8
        assert any("rejected, measured again" in m for m in seen) == spike, seen
    assert errors[True] < 1.5 * errors[False], errors


def test_a_range_too_small_stops_the_run_and_a_resume_with_a_larger_one_completes_it(tmp_path, capsys):
    """Periodic random at 4 Vpp with acc 3+Z on a 0.1 V range (10 m/s^2): every average
    clips, so the run stops after three (exit 3) and stderr says how to continue with a larger
    range. A setup changing anything else is refused. Resumed with that channel at 1 V the run
    completes, its FRFs as close to the truth as a run started at 1 V, and the run file says
    which session ran with which range; a later resume without a setup file takes it."""
    acc3 = 'name = "acc 3+Z"\ninput = 2\ndof = "3+Z"\nquantity = "acceleration"\nsensitivity_mv_per_unit = 10.0\n'

    def text(range_volt: float, drive_vpp: float = 4.0) -> str:
        t = random_setup(averages=6).replace("drive_vpp = 0.5", f"drive_vpp = {drive_vpp}")
        assert acc3 in t and f"drive_vpp = {drive_vpp}" in t
        return t.replace(acc3, acc3 + f"range_volt = {range_volt}\n")

    s, run = tmp_path / "s.toml", tmp_path / "run.h5"
    s.write_text(text(0.1))
    status, _ = cli([str(s), "--sim", "--out", str(run), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 3 and "DAQ overload" in err[0] and "acc 3+Z" in err[0], err
    assert err[-1].endswith(f"range_volt in the setup and continue with it: ssidlab acquire --resume {run} {s} --sim")

    other = tmp_path / "other.toml"
    other.write_text(text(1.0, drive_vpp=3.0))
    status, msg = cli(["--resume", str(run), str(other), "--sim"])
    assert status == 2 and "[random]" in msg and "only the channels' range_volt" in msg, msg
    with h5py.File(run) as f:
        assert f["acq"].attrs["state"].startswith("stopped: DAQ overload")

    s.write_text(text(1.0))
    status, _ = cli(["--resume", str(run), str(s), "--sim"])
    out = capsys.readouterr().out
    assert status == 0 and "DAQ input ranges changed for this session: 'acc 3+Z' 0.1 -> 1 V" in out, out
    clean = tmp_path / "clean.h5"
    assert cli([str(s), "--sim", "--out", str(clean), "--quiet"])[0] == 0
    world = build_world(parse_setup(text(1.0), str(s)))
    resumed, started = (float(np.median(frf_error(read_frf(p), world))) for p in (run, clean))
    assert read_frf(run).n_avg == 6 and resumed < 1.5 * started, (resumed, started)
    with h5py.File(run) as f:
        sessions = json.loads(f["acq/meta_json"][()])["sessions"]
    assert "range_volt_changed" not in sessions[0]
    assert sessions[1]["range_volt_changed"] == {"acc 3+Z": [0.1, 1.0]}
    assert load_resume_setup(run).channels[2].range_volt == 1.0


def interrupted_then_lab_moved(tmp_path, text: str, n_sub_lines: int):
    """A run of ``text`` on a simulated lab reached as real hardware (no sim switch),
    interrupted after ``n_sub_lines``; then the lab comes back on other ports and another
    CAN channel, as after a restart. Returns the run file, the setup file the run started
    with, and the new lab's handle and addressed setup (the caller stops the handle)."""
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    run, seen = tmp_path / "run.h5", []

    def echo(msg):
        seen.append(msg)
        if sum(m.lstrip().startswith("shaker") for m in seen) == n_sub_lines:
            raise KeyboardInterrupt

    first, inst = start_sim_lab(setup)
    try:
        old = tmp_path / "old.toml"
        old.write_text(pointed_at(text, inst))
        with pytest.raises(KeyboardInterrupt):
            run_test(load_setup(old), out=str(run), echo=echo)
        assert all_safe(first.world)
        # The lab comes back before the old one has gone, so no port can be the same.
        second, inst = start_sim_lab(setup)
    finally:
        first.stop()
    return run, old, second, inst


def test_a_resume_reaches_instruments_that_answer_at_new_addresses(tmp_path, capsys):
    """A resume usually follows a restart, after which the instruments may answer elsewhere
    (a serial port renumbered, an amplifier's address reassigned, the CAN adapter renamed).
    A run on a simulated lab reached as real hardware (no sim switch) is interrupted after
    three lines; the lab comes back on other ports and another CAN channel. Resumed with the
    stored setup, the run cannot reach the generator: it stops, the file still resumable.
    Resumed with a setup holding the new addresses (and the night shift's operator), it
    completes with every line within the accuracy asked of it, and the run file says which
    session ran through which addresses."""
    text = sine_setup(n_lines=8)
    run, old, second, inst = interrupted_then_lab_moved(tmp_path, text, 3)
    try:
        capsys.readouterr()
        status, _ = cli(["--resume", str(run)])
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 3 and "instrument lost (link down): gen0: cannot open serial port" in err[0], err
        assert err[-1].endswith("put that in the setup and continue with it: "
                                f"ssidlab acquire --resume {run} SETUP.toml"), err
        with h5py.File(run) as f:
            assert f["acq"].attrs["state"].startswith("stopped:") and f["acq/n_done"][0] == 3
        new = tmp_path / "new.toml"
        new.write_text(pointed_at(text, inst).replace('name = "daq test"\n', 'name = "daq test"\noperator = "night shift"\n'))
        status, _ = cli(["--resume", str(run), str(new), "--quiet"])
        assert status == 0 and all_safe(second.world)
        world = second.world
    finally:
        second.stop()
    frf = read_frf(run)
    assert np.all(frf.valid_mask())
    # Noise-free lines settle to the setup's accuracy (2e-3) on either side of the restart.
    err = frf_error(frf, world)
    assert np.all(err < 2e-3), err
    with h5py.File(run) as f:
        sessions = json.loads(f["acq/meta_json"][()])["sessions"]
    assert [s["resumed_at_record"] for s in sessions] == [0, 3]  # the failed resume reached no instrument
    changed = {(c["table"], c["key"]): (c["old"], c["new"]) for c in sessions[1]["setup_changed"]}
    old_inst = load_setup(old)
    assert set(changed) == {("generators", "url"), ("amplifiers", "port"), ("daq", "channel"), ("test", "operator")}
    assert changed[("generators", "url")] == (old_inst.generators[0].url, inst.generators[0].url)
    assert changed[("test", "operator")] == (None, "night shift")
    assert sessions[1]["range_volt_changed"] == {}
    assert load_resume_setup(run).generators[0].url == inst.generators[0].url


def _resume_on(tmp_path, run, setup_text: str, capsys):
    """``ssidlab acquire --resume RUN new.toml --quiet`` with ``setup_text`` in new.toml:
    the setup file, the exit status and the lines on stderr."""
    new = tmp_path / "new.toml"
    new.write_text(setup_text)
    capsys.readouterr()
    status, _ = cli(["--resume", str(run), str(new), "--quiet"])
    return new, status, capsys.readouterr().err.strip().splitlines()


def test_a_resume_stops_before_driving_when_another_generator_answers(tmp_path, capsys):
    """After a restart another generator (another serial in its *IDN?) answers at the
    setup's address: a swapped port would drive one shaker with another's signal. The
    resume stops before any output is switched on, naming both identities (exit 3, the file
    still resumable). With --new-instruments (the generator was replaced) it completes, and
    the run file records the replacement."""
    text = sine_setup(n_lines=6)
    run, _, second, inst = interrupted_then_lab_moved(tmp_path, text, 2)
    try:
        second.lab.generators[0].serial = "SN04711"
        new, status, err = _resume_on(tmp_path, run, pointed_at(text, inst), capsys)
        assert status == 3, err
        assert ("not the instruments of the run's last session: gen0 answers as 'ssidlab,SIM-33522,SN04711,1.0', "
                "in the last session as 'ssidlab,SIM-33522,SN00000,1.0'") in err[0], err
        assert "resume with --new-instruments" in err[0]
        # Not recorded, this session's setup: continuing without it would go back to the old addresses.
        assert err[1].endswith(f"continue with: ssidlab acquire --resume {run} {new}"), err
        assert err[2].endswith(f"an instrument was replaced, continue with: ssidlab acquire --resume {run} {new} "
                               "--new-instruments"), err
        assert not any(c.startswith("OUTP1 ON") or c.startswith("OUTP2 ON") for c in second.lab.generators[0].log)
        assert all_safe(second.world)
        with h5py.File(run) as f:
            assert f["acq"].attrs["state"].startswith("stopped: not the instruments") and f["acq/n_done"][0] == 2
        status, _ = cli(["--resume", str(run), str(new), "--new-instruments"])
        out = capsys.readouterr().out
        assert status == 0 and all_safe(second.world)
        assert "instruments replaced since the last session: gen0 answers as 'ssidlab,SIM-33522,SN04711,1.0'" in out
    finally:
        second.stop()
    with h5py.File(run) as f:
        sessions = json.loads(f["acq/meta_json"][()])["sessions"]
    assert len(sessions) == 2 and "instruments_replaced" not in sessions[0]
    assert sessions[1]["instruments_replaced"][0].startswith("gen0 answers as 'ssidlab,SIM-33522,SN04711,1.0'")
    assert cli(["run.h5", "--new-instruments"])[0] == 2  # only with --resume


def test_a_resume_stops_before_driving_on_a_lab_that_simulates_another_structure(tmp_path, capsys):
    """Simulated instruments answer alike whatever they simulate, so a run could be continued
    on a lab simulating another structure, its file then holding lines of two (QA: a --sim
    run resumed against an external sim-lab). The simulated DAQ front end's serial is the
    simulated structure's fingerprint: the resume stops before driving, as with another
    front end on hardware. (A lab restarted on the same structure answers as before:
    test_a_resume_reaches_instruments_that_answer_at_new_addresses.)"""
    text = sine_setup(n_lines=6)
    run, _, second, _ = interrupted_then_lab_moved(tmp_path, text, 2)
    second.stop()
    heavier = text + '\n[[sim.effects]]\ntype = "added_mass"\ndof = "3+Z"\nmass_kg = 0.25\n'
    other, inst = start_sim_lab(parse_setup(heavier, str(tmp_path / "heavier.toml")))
    try:
        _, status, err = _resume_on(tmp_path, run, pointed_at(text, inst), capsys)
        assert status == 3, err
        assert "not the instruments of the run's last session: the DAQ answers with serial" in err[0], err
        assert not any(c.startswith("OUTP1 ON") for c in other.lab.generators[0].log)
        assert all_safe(other.world)
    finally:
        other.stop()
    with h5py.File(run) as f:
        assert f["acq/n_done"][0] == 2


def test_a_resume_stops_when_two_amplifiers_answer_at_each_others_address(tmp_path, capsys):
    """Two amplifiers whose addresses swapped after a restart (their DHCP leases, say): the
    setup would run each shaker's amplifier with the other's gain and read the other's trips.
    Their serial numbers tell: the resume stops before any output is switched on, naming
    both. With the addresses put right it completes."""
    text = sine_setup(n_lines=4, two=True)
    run, _, second, inst = interrupted_then_lab_moved(tmp_path, text, 2)
    try:
        a0, a1 = inst.amplifiers
        good = tmp_path / "good.toml"
        good.write_text(pointed_at(text, inst))
        swapped = tmp_path / "swapped.toml"
        marker = f"port = {a0.port}\n"
        swapped.write_text(good.read_text().replace(marker, "PORT0").replace(f"port = {a1.port}\n", marker)
                           .replace("PORT0", f"port = {a1.port}\n"))
        capsys.readouterr()
        status, _ = cli(["--resume", str(run), str(swapped), "--quiet"])
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 3, err
        assert ("not the instruments of the run's last session: amp0 answers with serial 52002, in the last "
                "session with 52001; amp1 answers with serial 52001, in the last session with 52002") in err[0], err
        assert not any(a.model.enabled for a in second.lab.amplifiers) and all_safe(second.world)
        with h5py.File(run) as f:
            assert f["acq"].attrs["state"].startswith("stopped: not the instruments") and f["acq/n_done"][0] == 2
        status, _ = cli(["--resume", str(run), str(good), "--quiet"])
        assert status == 0 and all_safe(second.world)
    finally:
        second.stop()


def test_after_an_interlock_trip_the_fault_is_reset_by_the_check_and_the_run_resumes(tmp_path, capsys):
    """The door is opened mid-run on a lab reached as hardware: the amplifier trips and
    latches its fault, and the run stops. With the door still open, a reset is refused.
    Closed, a resume is still refused by the latch (exit 3), and stderr says to reset it;
    the check says not ready and how. `ssidlab check RUN.h5 --reset-faults` clears the latch
    without switching anything on, and the resume completes."""
    from ssidlab.cli import main

    text = sine_setup(n_lines=6)
    handle, inst = start_sim_lab(parse_setup(text, str(tmp_path / "s.toml")))
    try:
        lab, run, amp = tmp_path / "lab.toml", tmp_path / "run.h5", handle.lab.amplifiers[0]
        lab.write_text(pointed_at(text, inst))
        seen = []

        def echo(msg):
            seen.append(msg)
            if sum(m.lstrip().startswith("shaker") for m in seen) == 2:
                amp.set_interlock(False)

        with pytest.raises(RunStopped, match="amplifier interlock open"):
            run_test(load_setup(lab), out=str(run), echo=echo)
        assert all_safe(handle.world)
        capsys.readouterr()

        assert main(["check", str(run), "--reset-faults"]) == 3
        out = capsys.readouterr().out.splitlines()
        assert out[1].endswith("NOT READY: interlock open (door or E-stop); latched fault (interlock open) not reset: "
                               "its cause is still present"), out

        amp.set_interlock(True)
        assert cli(["--resume", str(run), "--json", str(tmp_path / "stop.json")])[0] == 3
        stop = json.loads((tmp_path / "stop.json").read_text())  # what a controlling program reads
        assert stop["remedy"] == "reset_faults" and stop["state"].startswith("stopped: amplifier fault")
        assert stop["n_records"] >= 2 and stop["continue_with"] == f"ssidlab acquire --resume {run}"
        err = capsys.readouterr().err.strip().splitlines()
        assert "amplifier fault: amp0: fault latched (interlock open)" in err[0], err
        assert err[2].endswith(f"reset the amplifier's latched fault: ssidlab check {run} --reset-faults; "
                               f"then continue with: ssidlab acquire --resume {run}"), err
        assert main(["check", str(run)]) == 3
        out = capsys.readouterr().out.splitlines()
        assert "NOT READY: fault latched since a trip (interlock open)" in out[1], out
        assert out[-1] == f"once a fault's cause is gone, reset it with: ssidlab check {run} --reset-faults", out

        assert main(["check", str(run), "--reset-faults"]) == 0
        out = capsys.readouterr().out.splitlines()
        assert "ok: latched fault (interlock open) reset, interlock closed, disabled, no fault" in out[1], out
        assert not amp.model.enabled
        assert cli(["--resume", str(run), "--quiet"])[0] == 0 and all_safe(handle.world)
    finally:
        handle.stop()
    assert np.all(read_frf(run).valid_mask())


def test_an_instrument_gone_silent_costs_the_stop_one_safe_state_attempt(tmp_path, monkeypatch):
    """The amplifier's Modbus server stops mid-run. Its safe state is attempted once, not
    again by the rig's close and by the driver's own close: each attempt on an instrument
    that does not answer waits out its time-outs (a frozen lab took 30 s to exit)."""
    from drivers.amplifier import ShakerAmplifier

    attempts: list[str] = []
    real = ShakerAmplifier.safe_state

    async def counted(self):
        attempts.append(self.name)
        return await real(self)

    monkeypatch.setattr(ShakerAmplifier, "safe_state", counted)
    msg, _ = stopped_run(tmp_path, lambda lab: lab.amplifiers[0].stop())
    assert msg.startswith("safe state NOT confirmed (check the instruments): amp0:"), msg
    assert attempts.count("amp0") == 1, attempts


def test_a_heartbeat_fault_found_while_the_line_reads_the_status_is_named(tmp_path):
    """The driver's monitor found the stalled heartbeat and disabled the amplifier between
    the line check's look at the driver's faults and its status read (a CI run under load):
    the status then reads disabled with no fault latched in the amplifier, and the run
    stopped saying "amplifier tripped (none)". The monitor's reason is what is said."""
    from daq.rig import InstrumentRig
    from drivers.errors import HeartbeatLost

    setup = parse_setup(sine_setup(), str(tmp_path / "s.toml"))
    handle, inst = start_sim_lab(setup)
    rig = InstrumentRig(inst)
    try:
        rig.prepare()
        (amp,) = rig.amps.values()
        read = amp.read_status

        def monitor_fires_then_read():
            amp._call(amp.amp._set_fault(HeartbeatLost("amp0: heartbeat stopped at 7 for 1.0 s")))
            return read()

        amp.read_status = monitor_fires_then_read
        with pytest.raises(HeartbeatLost, match="heartbeat stopped"):
            rig.line_check()
    finally:
        problems = rig.safe_state()
        rig.close()
        handle.stop()
    assert not problems
