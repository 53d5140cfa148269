"""What the Setup tab shows of the example setup (tui.setup_view): pure text and rows."""

from __future__ import annotations

from pathlib import Path

from test_daq_helpers import random_setup

from daq.setup import load_setup, parse_setup
from tui.setup_view import (
    channel_options,
    channel_rows,
    configured_instrument_rows,
    describe_setup,
    instruments_in_use_rows,
)

SETUP = Path(__file__).resolve().parents[1] / "examples" / "setup_sim.toml"


def test_setup_texts_and_rows_of_the_example():
    s = load_setup(SETUP)
    text = describe_setup(s).splitlines()
    assert len(text) == 3 and "21 channels, 2 shakers (11+Z, 16+Z)" in text[0]
    assert text[1].startswith("stepped sine") and text[2].startswith("limits: drive")
    assert configured_instrument_rows(s) == [
        ("gen0", "generator", "/dev/ttyUSB0", "not checked (F4)", ""),
        ("amp0", "amplifier", "192.168.0.10:502", "not checked (F4)", ""),
        ("amp1", "amplifier", "192.168.0.11:502", "not checked (F4)", ""),
        ("daq", "daq", "socketcan:can0", "not checked (F4)", "")]
    rows = channel_rows(s)
    assert len(rows) == 21 and all(len(r) == 7 for r in rows)
    options = channel_options(s)
    assert len(options) == len(s.outputs) * len(s.inputs)
    assert options[0] == (f"{s.outputs[0]} / {s.inputs[0]}", (0, 0))


def test_instruments_in_use_name_real_addresses_or_simulated():
    s = load_setup(SETUP)
    ev = {"identities": {"generators": {"gen0": "SIM,GEN"}, "amplifiers": {"amp1": "AMP 2"},
                         "daq": {"serial": 7, "fw_version": "1.2", "other": "x"}}}
    real = instruments_in_use_rows({**ev, "simulated": False}, s)
    assert real == [("gen0", "generator", "/dev/ttyUSB0", "in use by the run", "SIM,GEN"),
                    ("amp1", "amplifier", "192.168.0.11:502", "in use by the run", "AMP 2"),
                    ("daq", "daq", "socketcan:can0", "in use by the run", "serial 7, fw_version 1.2")]
    sim = instruments_in_use_rows({**ev, "simulated": True}, s)
    assert {r[2] for r in sim} == {"simulated"}


def test_same_pair_passes_a_channel_on_by_its_dofs():
    from tui.setup_view import pair_options, same_pair

    assert pair_options(["a", "b"], ["a"]) == [("a / a", (0, 0)), ("b / a", (1, 0))]
    assert same_pair((1, 0), ["a", "b"], ["a"], ["b", "a"], ["a"]) == (0, 0)
    assert same_pair((1, 0), ["a", "b"], ["a"], ["a"], ["a"]) is None  # "b" not there


def test_the_setup_tab_shows_rms_limits_when_set():
    lim = describe_setup(parse_setup(random_setup(kind="random") + "[limits]\nmax_accel_rms_m_per_s2 = 2.5\n"))
    assert "reaction inf N; RMS accel 2.5 m/s2; min coherence" in lim.splitlines()[2]
    assert "RMS" not in describe_setup(load_setup(SETUP))  # none set: the line as before
