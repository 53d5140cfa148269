"""Setup files: the example parses, bad files get one precise line naming the key (exit 2)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from daq.setup import load_setup, parse_setup
from ssid.errors import InputError

from test_daq_helpers import cli, random_setup, sine_setup

ROOT = Path(__file__).resolve().parents[1]


def test_example_setup_is_the_demo_setup():
    from ssidlab.lab_demo import demo_setup_text

    text = (ROOT / "examples" / "setup_sim.toml").read_text()
    assert text == demo_setup_text()
    s = load_setup(ROOT / "examples" / "setup_sim.toml")
    assert len(s.channels) == 21 and s.inputs == ["11+Z", "16+Z"] and s.reactions == ["4+Z", "8+Z", "18+Z"]
    assert len(s.outputs) == 16 and s.roles()["force"] == [0, 1]


def test_free_example_is_the_stand_example_off_its_stand():
    """TOML has no include, so examples/setup_sim_free.toml repeats setup_sim.toml; this keeps
    the two the same test but for what makes one free: no load cells, no stand, its own name
    and output files."""
    import tomllib

    stand = tomllib.loads((ROOT / "examples" / "setup_sim.toml").read_text())
    free = tomllib.loads((ROOT / "examples" / "setup_sim_free.toml").read_text())
    assert free["test"]["name"] != stand["test"]["name"]
    assert free["output"]["file"] == "free.h5" and stand["output"]["file"] == "run.h5"
    for t in (stand, free):
        del t["test"]["name"], t["output"]["file"], t["output"]["uff"]
    stand["channels"] = [c for c in stand["channels"] if c["quantity"] != "reaction"]
    del stand["sim"]["stand"]
    assert free == stand
    s = load_setup(ROOT / "examples" / "setup_sim_free.toml")
    assert s.reactions == [] and len(s.outputs) == 16 and s.inputs == ["11+Z", "16+Z"]


@pytest.mark.parametrize("edit, key", [
    (("f_max_hz = 200.0", "f_max_hz = 50.0"), "[stepped_sine] f_max_hz"),
    (("force_n = 1.0", "force_n = -1"), "[stepped_sine] force_n"),
    # TOML writes inf; it was accepted as a force target no drive reaches
    (("force_n = 1.0", "force_n = inf"), "[stepped_sine] force_n: must be a finite number, got inf"),
    (("sample_rate_hz = 4096", "sample_rate_hz = 4096.5"), "[daq] sample_rate_hz"),
    (("sample_rate_hz = 4096", "sample_rate_hz = 4096\npassband_fraction = 0.6"), "[daq] passband_fraction"),
    # was an instrument "lost (link down)" to check, exit 3, once the run had started (QA)
    (("sample_rate_hz = 4096", 'sample_rate_hz = 4096\ninterface = "socketcann"'), "[daq] interface: must be one of"),
    (("sensitivity_mv_per_unit = 22.5", "sensitivity_mv_per_unit = 0"), "[[channels]] #1 sensitivity_mv_per_unit"),
    (('quantity = "force"', 'quantity = "forse"'), "[[channels]] #1 quantity"),
    (('force_channel = "force 1+Z"', 'force_channel = "acc 1+Z"'), "[[shakers]] #1 force_channel"),
    (('amplifier = "amp0"\nforce', 'amplifier = "amp9"\nforce'), "[[shakers]] #1 amplifier"),
    (("refine = 3", "refine = 3\nrefien = 2"), "[stepped_sine] refien: unknown key"),
    (('type = "stepped_sine"', 'type = "chirp"'), "[excitation] type"),
    (('structure = "example"', "structure = 3"), "[sim] structure"),
    (('structure = "example"', 'structure = "example"\nsensitivity_error = { "force 9+Z" = 1.05 }'),
     "[sim] sensitivity_error: no channel named 'force 9+Z'"),
    (('structure = "example"', 'structure = "example"\nsensitivity_error = { "force 1+Z" = -1 }'),
     "[sim] sensitivity_error: 'force 1+Z': a factor between 0.1 and 10"),
])
def test_bad_setup_names_the_key(tmp_path, edit, key):
    text = sine_setup()
    assert edit[0] in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(edit[0], edit[1], 1))
    if key.startswith("[sim]"):
        from daq.simlab import build_world

        with pytest.raises(InputError) as e:
            build_world(load_setup(p))
    else:
        with pytest.raises(InputError) as e:
            load_setup(p)
    msg = str(e.value)
    assert key in msg and str(p) in msg and "\n" not in msg


def test_an_empty_setup_file_is_called_empty(tmp_path):
    """Was "[output] file: missing (required)" (QA: `ssidlab check run.h5` on an empty file)."""
    p = tmp_path / "run.h5"
    p.write_text("\n")
    with pytest.raises(InputError, match=re.escape(f"{p}: empty file (a setup file, SETUP.toml, was expected)")):
        load_setup(p)


def test_band_beyond_the_daq_passband_is_refused(tmp_path):
    """At 4096 S/s the front end's filter passes up to 0.45 fs = 1843.2 Hz: a stepped sine
    or random band past it is refused, naming the limit and the way out; a band up to it is
    taken, and an analyser-style 1/2.56 narrows it."""
    p = tmp_path / "s.toml"
    for text in (sine_setup(f_max=1900.0), random_setup().replace("f_max_hz = 200", "f_max_hz = 1900")):
        p.write_text(text)
        with pytest.raises(InputError) as e:
            load_setup(p)
        assert "f_max_hz: 1900 Hz is beyond the DAQ's alias-free band, 1843.2 Hz" in str(e.value)
        assert "raise sample_rate_hz" in str(e.value)
    p.write_text(sine_setup(f_max=1843.2))
    assert load_setup(p).sine.f_max_hz == 1843.2
    p.write_text(sine_setup(f_max=1843.2).replace("sample_rate_hz = 4096", "sample_rate_hz = 4096\npassband_fraction = 0.390625"))
    with pytest.raises(InputError, match="alias-free band, 1600 Hz"):
        load_setup(p)


def test_a_random_level_beyond_a_drive_limit_is_refused(tmp_path):
    """A random run's level is fixed: one above what the generator takes (4 Vpp here) is a
    setup error, named before any file is made; it stopped every run at its start as an
    instrument error ("amplitude 6.0 Vpp outside [0.002, 4]")."""
    p = tmp_path / "s.toml"
    p.write_text(random_setup().replace("drive_vpp = 0.5", "drive_vpp = 6.0"))
    with pytest.raises(InputError) as e:
        load_setup(p)
    assert "[random] drive_vpp: 6 Vpp is more than shaker '1+Z' may get, 4 Vpp" in str(e.value)
    p.write_text(random_setup().replace("drive_vpp = 0.5", "drive_vpp = 4.0"))
    assert load_setup(p).random.drive_vpp == 4.0


@pytest.mark.parametrize("extra, limits, gain, said", [
    ("initial_vpp = 6.0", "", "2.0", "[stepped_sine] initial_vpp: 6 Vpp is more than shaker '1+Z' may get, 4 Vpp"),
    ("", "max_force_n = 1.0", "2.0", "[stepped_sine] force_n: 1 N is not below [limits] max_force_n (1 N)"),
    ("min_dwell_s = 0.5\nmax_dwell_s = 0.1", "", "2.0", "[stepped_sine] max_dwell_s: must be at least min_dwell_s"),
    ("", "", "0.0", "[[amplifiers]] #1 gain_v_per_v"),
])
def test_a_sine_setup_that_cannot_do_what_it_asks_is_refused(tmp_path, extra, limits, gain, said):
    """Each was taken and driven (QA): a first drive above the generator's 4 Vpp, cut to the
    limit, overshot the force limit and aborted the first line; a force target at the force
    limit held 13 sub-lines below it; the dwell bounds crossed; an amplifier gain of 0 ran its
    shaker at full drive for no force on every line."""
    p = tmp_path / "s.toml"
    text = sine_setup(extra=extra, limits=limits)
    assert text.count("gain_v_per_v = 2.0") == 1
    p.write_text(text.replace("gain_v_per_v = 2.0", f"gain_v_per_v = {gain}"))
    with pytest.raises(InputError) as e:
        load_setup(p)
    assert said in str(e.value) and str(p) in str(e.value), str(e.value)
    p.write_text(sine_setup(extra="initial_vpp = 4.0\nmin_dwell_s = 0.1\nmax_dwell_s = 0.1",
                            limits="max_force_n = 1.01"))
    load_setup(p)  # at the bounds: taken


def test_the_steady_state_check_is_refused_for_continuous_random(tmp_path):
    """``accuracy`` and ``max_settle_s`` set the steady-state check of periodic and burst
    random; set for continuous random they would do nothing, so they are refused, not
    ignored."""
    p = tmp_path / "s.toml"
    p.write_text(random_setup(kind="random").replace("drive_vpp = 0.5", "drive_vpp = 0.5\naccuracy = 1e-3"))
    with pytest.raises(InputError, match=r"\[random\] accuracy: applies to kind = \"periodic\" or \"burst\" only"):
        load_setup(p)
    p.write_text(random_setup().replace("drive_vpp = 0.5", "drive_vpp = 0.5\naccuracy = 1e-4\nmax_settle_s = 5"))
    spec = load_setup(p).random
    assert (spec.accuracy, spec.max_settle_s) == (1e-4, 5.0)


def test_cli_bad_input_is_one_line_exit_2(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[excitation]\ntype = 'stepped_sine'\n[output\n")
    status, err = cli([str(p)])
    assert status == 2 and "not valid TOML" in err and "\n" not in err
    status, err = cli([str(tmp_path / "missing.toml")])
    assert status == 2 and "no such file" in err
    status, err = cli([])
    assert status == 2 and "setup file is required" in err
    status, err = cli(["--resume", str(tmp_path / "nothing.h5")])
    assert status == 2 and "no such run file" in err


def test_missing_required_and_cross_checks():
    with pytest.raises(InputError, match=r"\[output\] file: missing"):
        parse_setup(sine_setup().replace('file = "run.h5"', ""), "s.toml")
    with pytest.raises(InputError, match=r"\[\[shakers\]\] #1 dof: no acceleration channel"):
        parse_setup(sine_setup().replace('dof = "1+Z"\nquantity = "acceleration"', 'dof = "2+Z"\nquantity = "acceleration"'), "s.toml")
    with pytest.raises(InputError, match=r"\[stepped_sine\] control"):
        parse_setup(sine_setup(extra='control = "force 1+Z"'), "s.toml")


def test_a_resume_may_change_ranges_addresses_operator_and_file_names_only(tmp_path):
    """setup_changes_on_resume: a changed range_volt, instrument address, operator or output
    file name is named with its old and new value in effect (defaults filled in), a changed
    comment or a default written out is no change, and anything else is refused naming the
    table where it differs."""
    from daq.resume import range_changes, setup_changes_on_resume

    base = sine_setup()
    stored = parse_setup(base, "s.toml")
    acc3 = 'name = "acc 3+Z"\ninput = 2\ndof = "3+Z"\nquantity = "acceleration"\nsensitivity_mv_per_unit = 10.0\n'
    assert acc3 in base

    def changed(*edits: tuple[str, str]) -> list[tuple]:
        text = base
        for old, new in edits:
            assert old in text
            text = text.replace(old, new)
        return [(c.where, c.key, c.old, c.new)
                for c in setup_changes_on_resume(stored, parse_setup(text, "new.toml"), "run.h5")]

    assert changed((acc3, acc3 + "range_volt = 2.5\n")) == [("[[channels]] 'acc 3+Z'", "range_volt", 10.0, 2.5)]
    assert changed((acc3, acc3 + "range_volt = 10.0  # the default, written out\n")) == []
    moved = changed(('url = "socket://127.0.0.1:1"', 'url = "/dev/ttyUSB1"\ntimeout_s = 3.0'),
                    ('name = "amp0"\n', 'name = "amp0"\nhost = "10.0.0.7"\n'),
                    ("[daq]\n", '[daq]\ninterface = "socketcan"\nchannel = "can1"\n'),
                    ('name = "daq test"\n', 'name = "daq test"\noperator = "night shift"\n'),
                    ('file = "run.h5"\n', 'file = "run2.h5"\nuff = "run2.uff"\n'))
    assert moved == [("[[generators]] 'gen0'", "url", "socket://127.0.0.1:1", "/dev/ttyUSB1"),
                     ("[[generators]] 'gen0'", "timeout_s", 1.0, 3.0),
                     ("[[amplifiers]] 'amp0'", "host", "127.0.0.1", "10.0.0.7"),
                     ("[daq]", "interface", "virtual", "socketcan"),
                     ("[daq]", "channel", "ssidlab-daq", "can1"),
                     ("[test]", "operator", None, "night shift"),
                     ("[output]", "file", "run.h5", "run2.h5"),
                     ("[output]", "uff", None, "run2.uff")], moved
    new = parse_setup(base.replace(acc3, acc3 + "range_volt = 2.5\n").replace('port = 1\n', 'port = 5020\n'), "n.toml")
    both = setup_changes_on_resume(stored, new, "run.h5")
    assert [str(c) for c in both] == ["[[channels]] 'acc 3+Z' range_volt 10.0 -> 2.5",
                                      "[[amplifiers]] 'amp0' port 1 -> 5020"]
    assert range_changes(both) == {"acc 3+Z": (10.0, 2.5)}
    for old, new, where in [(acc3, acc3.replace("10.0", "10.2"), "[[channels]] 'acc 3+Z'"),
                            ("max_vpp = 4.0", "max_vpp = 3.0", "[[generators]] 'gen0'"),
                            ("gain_v_per_v = 2.0", "gain_v_per_v = 2.5", "[[amplifiers]] 'amp0'"),
                            ("sample_rate_hz = 4096", "sample_rate_hz = 8192", "[daq]"),
                            ('name = "daq test"', 'name = "another test"', "[test]"),
                            ("force_n = 1.0", "force_n = 2.0", "[stepped_sine]"),
                            ("[limits]\n", "[limits]\nmax_force_n = 40\n", "[limits]")]:
        with pytest.raises(InputError, match=re.escape(f"new.toml: differs from the setup of the run run.h5 in {where}")):
            changed((old, new))


def test_a_resume_compares_the_serials_of_the_instruments_that_report_one():
    """instruments_not_the_same: a generator is known by its *IDN? maker, model and serial (not
    its firmware), an amplifier and the DAQ by their serials, and none by its address. A run
    file written before the amplifiers reported a serial ("model 0x5A01 at ...") has nothing
    to compare them with."""
    from daq.resume import instruments_not_the_same

    def ids(gen="ACME,SG2,SN1234,1.1", amp0="model 0x5A01 serial 52001 at 10.0.0.7:502", daq=7):
        return {"generators": {"gen0": gen}, "amplifiers": {"amp0": amp0}, "daq": {"serial": daq}}

    before = ids()
    assert instruments_not_the_same(before, ids(gen="ACME,SG2,SN1234,1.2",
                                                amp0="model 0x5A01 serial 52001 at 10.0.0.9:5020")) == []
    assert instruments_not_the_same(before, ids(amp0="model 0x5A01 serial 52002 at 10.0.0.7:502", daq=8)) == [
        "amp0 answers with serial 52002, in the last session with 52001",
        "the DAQ answers with serial 8, in the last session with 7"]
    assert instruments_not_the_same(before, ids(gen="ACME,SG2,SN1235,1.1")) == [
        "gen0 answers as 'ACME,SG2,SN1235,1.1', in the last session as 'ACME,SG2,SN1234,1.1'"]
    old_file = ids(amp0="model 0x5A01 at 10.0.0.7:502")
    assert instruments_not_the_same(old_file, ids(amp0="model 0x5A01 serial 52002 at 10.0.0.7:502")) == []


def test_the_advice_after_a_stop_follows_the_fault_that_stopped_the_run():
    """resume_remedy: from the run file's state alone (all the TUI has), what must change
    before a resume gets past the stop (a range, an address, an amplifier's latched trip,
    the instruments); nothing when a plain resume is the way on, or when the safe state was
    not confirmed (the instruments come first)."""
    from daq.safety import NOT_THE_SAME_INSTRUMENTS, describe_fault, resume_remedy
    from drivers.errors import (AmplifierFault, ConnectionLost, FramesLost, HeartbeatLost, InstrumentTimeout,
                                InterlockOpen, SensorOverload)

    def stopped(exc: Exception) -> str:
        return f"stopped: {describe_fault(exc)}"

    overload = stopped(SensorOverload("daq: over range on acc 3+Z (samples clipped)", ["acc 3+Z"]))
    link = stopped(ConnectionLost("gen0: cannot open serial port /dev/ttyUSB0"))
    assert resume_remedy(overload, sim=False) == resume_remedy(overload, sim=True) == "range_volt"
    assert resume_remedy(link, sim=False) == "address"
    assert resume_remedy(link, sim=True) is None  # the simulated lab's addresses are its own
    other = f"stopped: {NOT_THE_SAME_INSTRUMENTS}: gen0 answers as 'ACME,SG2,SN1235,1.1', in the last session as ..."
    assert resume_remedy(other, sim=True) == "new_instruments"
    for trip in [InterlockOpen("amp0: interlock open"), HeartbeatLost("amp0: heartbeat stopped at 12 for 1.1 s"),
                 AmplifierFault("amp0: amplifier tripped (over-temperature)", 2)]:
        assert resume_remedy(stopped(trip), sim=False) == "reset_faults"
        assert resume_remedy(stopped(trip), sim=True) is None  # a resume starts the simulated lab afresh
    for plain in [stopped(InstrumentTimeout("gen0: no reply")), stopped(FramesLost("daq: frame gap on input 2")),
                  "interrupted", "complete", "running", None,
                  overload + "; safe state not confirmed: gen0: no reply"]:
        assert resume_remedy(plain, sim=False) is None, plain


def test_a_bad_sim_table_is_refused_before_the_run_file_exists(tmp_path):
    """The simulated world is built before the run file is created: a bad [sim] table left
    a file in state "failed" at the output path, which then blocked both the corrected
    setup's run ("exists already") and a resume ("differs in [sim]")."""
    from daq.run import run_test

    text = sine_setup(n_lines=3).replace("[sim]\n", "[sim]\noversample = 0\n")
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    with pytest.raises(InputError, match=r"\[sim\] oversample: must be in \[1, 64\], got 0"):
        run_test(setup, out=str(tmp_path / "run.h5"), sim=True, echo=lambda m: None)
    assert not (tmp_path / "run.h5").exists()


@pytest.mark.parametrize("effect, said", [
    # Each was "[sim]: the assembled system is unstable (check M, C, K signs)", naming no entry (QA).
    ('type = "added_mass"\ndof = "6+Z"\nmass_kg = -0.9',
     "[[sim.effects]] #1 (added_mass at 6+Z) mass_kg = -0.9: makes the assembled system unstable: "
     "the mass matrix is no longer positive definite"),
    ('type = "coupling_spring"\ndof_a = "7+Z"\ndof_b = "8+Z"\nstiffness_n_per_m = -3e6',
     "[[sim.effects]] #1 (coupling_spring between 7+Z and 8+Z) stiffness_n_per_m = -3e+06: makes the "
     "assembled system unstable: the stiffness matrix gets a negative eigenvalue"),
    ('type = "attached_oscillator"\ndof = "3+Z"\nmass_kg = 0.2\nstiffness_n_per_m = -1e5\ndamping_n_s_per_m = 1',
     "[[sim.effects]] #1 (attached_oscillator at 3+Z) stiffness_n_per_m = -100000: an attached "
     "oscillator's spring must be > 0"),
    ('type = "attached_oscillator"\ndof = "3+Z"\nmass_kg = 0\nstiffness_n_per_m = 1e5\ndamping_n_s_per_m = 1',
     "[[sim.effects]] #1 (attached_oscillator at 3+Z) mass_kg = 0: an attached oscillator's mass must be > 0"),
    ('type = "grounded_damper"\ndof = "3+Z"\ndamping_n_s_per_m = -50',
     "[[sim.effects]] #1 (grounded_damper at 3+Z) damping_n_s_per_m = -50: a damper's damping must be >= 0"),
])
def test_a_sim_effect_the_lab_cannot_take_is_named(tmp_path, effect, said):
    """The payload example setup with its hidden mass replaced by one bad entry: the error
    names the entry (its place, type, DOF) and the value at fault, and says why; acquire
    exits 2 with that line before anything is started."""
    from daq.simlab import example_setup_text

    text = example_setup_text()
    p = tmp_path / "bad.toml"
    p.write_text(text[:text.index("[[sim.effects]]")] + "[[sim.effects]]\n" + effect + "\n")
    status, err = cli([str(p), "--sim", "--out", str(tmp_path / "run.h5")])
    assert status == 2 and err.startswith(f"{p}: {said}")
    assert "\n" not in err and not (tmp_path / "run.h5").exists()


def test_the_second_of_two_sim_effects_is_named_when_it_makes_the_lab_unstable(tmp_path):
    """A harmless mass first, then a spring that makes the structure diverge: the spring's
    entry is named, as acting with the ones before it."""
    from daq.simlab import build_world, example_setup_text

    text = example_setup_text() + ('\n[[sim.effects]]\ntype = "coupling_spring"\ndof_a = "7+Z"\ndof_b = "8+Z"\n'
                                   'stiffness_n_per_m = -3e6\n')
    with pytest.raises(InputError) as e:
        build_world(parse_setup(text, "two.toml"))
    assert str(e.value).startswith("two.toml: [[sim.effects]] #2 (coupling_spring between 7+Z and 8+Z) "
                                   "stiffness_n_per_m = -3e+06: makes the assembled system unstable")
    assert str(e.value).endswith("(with the effects before it)")
