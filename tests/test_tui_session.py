"""What the TUI decides before a run touches anything (tui.session): which run file a run may
write, and what the instrument check (F4) says, against the simulated lab on loopback and
against addresses where nothing answers."""

from __future__ import annotations

import dataclasses
import socket
from pathlib import Path

import h5py

from daq.check import check_lab
from daq.setup import load_setup
from tui.session import RunOutcome, run_file_choice
from tui.setup_view import checked_instrument_rows

SETUP = Path(__file__).resolve().parents[1] / "examples" / "setup_sim.toml"


def _run_file(path: Path, state: str) -> Path:
    with h5py.File(path, "w") as f:
        f.create_group("acq").attrs["state"] = state
    return path


def test_run_file_choice_starts_resumes_or_refuses(tmp_path):
    assert run_file_choice(tmp_path / "new.h5") == (None, False)
    assert run_file_choice(_run_file(tmp_path / "cut.h5", "interrupted")) == (None, True)
    refusal, resume = run_file_choice(_run_file(tmp_path / "done.h5", "complete"))
    assert not resume and refusal == f"{tmp_path / 'done.h5'} holds a complete run: choose another run file"
    (tmp_path / "notes.h5").write_text("not HDF5")
    refusal, _ = run_file_choice(tmp_path / "notes.h5")
    assert refusal.endswith("exists and is not a run file: choose another run file")
    refusal, _ = run_file_choice(tmp_path / "nowhere" / "run.h5")
    assert refusal is not None and "does not exist" in refusal and "\n" not in refusal


def test_instrument_check_of_the_simulated_lab_all_answer():
    states = check_lab(load_setup(SETUP), sim=True)
    rows, verdict = checked_instrument_rows(states, sim=True)
    assert verdict == "instruments: all 4 answered and ready (simulated lab)"
    assert [r[0] for r in rows] == ["gen0", "amp0", "amp1", "daq"]
    assert all(r[3].startswith("ok: ") and r[4] for r in rows)


def test_instrument_check_says_which_did_not_answer(tmp_path):
    setup = load_setup(SETUP)
    with socket.socket() as s:  # a loopback port nobody listens on once closed
        s.bind(("127.0.0.1", 0))
        closed_port = s.getsockname()[1]
    setup.generators = [dataclasses.replace(g, url=str(tmp_path / "no-such-tty")) for g in setup.generators]
    setup.amplifiers = [dataclasses.replace(setup.amplifiers[0], host="127.0.0.1", port=closed_port)]
    setup.daq = dataclasses.replace(setup.daq, interface="virtual", channel="ssidlab-test-nobody")
    rows, verdict = checked_instrument_rows(check_lab(setup, sim=False), sim=False)
    assert verdict == "instruments: 3 of 3 did not answer (gen0, amp0, daq)"
    assert [r[:3] for r in rows] == [("gen0", "generator", str(tmp_path / "no-such-tty")),
                                     ("amp0", "amplifier", f"127.0.0.1:{closed_port}"),
                                     ("daq", "daq", "virtual:ssidlab-test-nobody")]
    assert all(r[3].startswith("NO ANSWER: ") and len(r[3]) > len("NO ANSWER: ") and not r[4] for r in rows)


def test_run_summary_never_calls_an_unconfirmed_safe_state_safe():
    fault = RunOutcome(3, False, "run.h5", "stopped: instrument lost (link down): amp0: gone")
    assert fault.summary().startswith("run stopped safely by a fault")
    unsafe = RunOutcome(3, True, "run.h5", "interrupted; safe state not confirmed: amp0: no reply")
    text = unsafe.summary()
    assert "SAFE STATE NOT CONFIRMED" in text and "safely" not in text and "amp0: no reply" in text
