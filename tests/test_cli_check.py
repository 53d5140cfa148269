"""``ssidlab check``: the instruments of a setup, each opened, identified and released, with
a verdict a script can act on (exit 0 ready, 3 not), against simulated instruments on their
real transports."""

from __future__ import annotations

import json
from pathlib import Path

from daq.setup import parse_setup
from daq.simlab import start_sim_lab
from ssidlab.cli import main

from test_daq_helpers import pointed_at, sine_setup

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "setup_sim.toml"


def test_the_simulated_lab_answers_and_is_ready(tmp_path, capsys):
    status = main(["check", str(EXAMPLE), "--sim", "--json", str(tmp_path / "check.json")])
    out = capsys.readouterr().out.splitlines()
    assert status == 0, out
    assert out[-1] == "instruments: all 4 answered and ready (simulated lab)"
    assert [line.split()[0] for line in out[:-1]] == ["gen0", "amp0", "amp1", "daq"]
    assert "serial 52001" in out[1] and "ok: interlock closed, disabled, no fault" in out[1], out
    assert "firmware 1.0" in out[3], out
    saved = json.loads((tmp_path / "check.json").read_text())
    assert saved["ready"] is True and len(saved["instruments"]) == 4


def test_an_open_interlock_and_a_daq_short_of_inputs_are_not_ready(tmp_path, capsys):
    """The lab answers as real hardware (no sim switch), but amp0's interlock is open and the
    setup wires a channel to an input the DAQ lacks: a run would stop at its start, so the
    check says which and why, and exits 3."""
    text = sine_setup(two=True)
    handle, inst = start_sim_lab(parse_setup(text, str(tmp_path / "s.toml")))
    try:
        n_inputs = len(handle.world.sensors)
        extra = (f'\n[[channels]]\nname = "acc 9+Z"\ninput = {n_inputs}\ndof = "9+Z"\nquantity = "acceleration"\n'
                 'sensitivity_mv_per_unit = 10.0\n')
        (tmp_path / "lab.toml").write_text(pointed_at(text, inst) + extra)
        handle.lab.amplifiers[0].set_interlock(False)
        status = main(["check", str(tmp_path / "lab.toml"), "--json", str(tmp_path / "check.json")])
        out = capsys.readouterr().out.splitlines()
        assert not any(a.model.enabled for a in handle.lab.amplifiers)
    finally:
        handle.stop()
    assert status == 3, out
    assert out[-1] == (f"instruments: not ready: amp0: interlock open (door or E-stop); daq: {n_inputs} inputs "
                       f"(0..{n_inputs - 1}), the setup uses {n_inputs} ('acc 9+Z')"), out
    assert "NOT READY" in out[1] and "ok: interlock closed" in out[2], out
    saved = json.loads((tmp_path / "check.json").read_text())
    assert [s["ready"] for s in saved["instruments"]] == [True, False, True, False]


def test_instruments_that_do_not_answer_exit_3_and_a_bad_setup_exits_2(tmp_path, capsys):
    text = sine_setup()  # its generator at a loopback port where nothing listens
    (tmp_path / "s.toml").write_text(text)
    assert main(["check", str(tmp_path / "s.toml"), "--timeout-s", "0.2"]) == 3
    out = capsys.readouterr().out.splitlines()
    assert out[-1].startswith("instruments: 3 of 3 did not answer (gen0, amp0, daq)"), out
    assert main(["check", str(tmp_path / "nowhere.toml")]) == 2
    assert main(["check", str(tmp_path / "s.toml"), "--timeout-s", "0"]) == 2
    assert main(["check", str(tmp_path / "s.toml"), "--json", str(tmp_path / "nowhere" / "c.json")]) == 2
    assert main(["check", str(tmp_path / "s.toml"), "--json", str(tmp_path / "s.toml")]) == 2  # its own setup
    assert "3 of 3 did not answer" not in capsys.readouterr().out  # refused before any instrument is asked
