"""A miscalibrated accelerometer (and load cell) in the simulated lab, end to end: the run is acquired through
the real drivers with ``[sim] sensitivity_error`` (the transducer's true sensitivity 1.25
times its calibration sheet's), and the Results tab's analysis (``tui.results.analyse_run``
against the lab's nominal model) must say that channel gains, not a physical effect, explain
the gap, naming the channel and its factor."""

from __future__ import annotations

import pytest

from test_daq_helpers import sine_setup


def test_a_miscalibrated_accelerometer_is_flagged_with_its_factor(tmp_path):
    from daq.run import run_test
    from daq.setup import parse_setup
    from tui.results import analyse_run

    text = sine_setup(n_lines=6, sim_extra='sensitivity_error = { "acc 3+Z" = 1.25 }')
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    run_test(setup, out=str(tmp_path / "run.h5"), sim=True, echo=lambda m: None)
    res = analyse_run(tmp_path / "run.h5", setup, sim=True)
    cal = res.discrepancy["calibration"]
    assert cal["flagged"], cal["text"]
    gains = cal["output_gain"]
    others = [g for dof, g in gains.items() if dof != "3+Z"]
    # The accelerometer puts out 1.25 times the volts its sheet says: every FRF of 3+Z reads
    # 1.25 times the truth. The run's accuracy (2e-3 per line) fixes the ratio well inside 1 %.
    assert gains["3+Z"] / (sum(others) / len(others)) == pytest.approx(1.25, rel=0.01), gains
    said = [n for n in res.notes if n.startswith("warning: channel gains explain")]
    assert len(said) == 1 and "output '3+Z' x 1.25" in said[0], res.notes


def test_a_miscalibrated_load_cell_is_flagged_when_the_substructure_model_takes_the_reactions(tmp_path):
    """The load cell at the stand's DOF 14+Z puts out 1.25 times the volts its sheet says.
    Analysed with the structure's model alone (the TUI with a model file: loaded by the
    measured reactions), the reaction it measured is 1.25 times the force; the workflow named
    a coupling spring at 13+Z-14+Z for it (gap 28 -> 6). Now the load cell's gain is fitted
    too (1.2518 here; noise-free run, 2e-3 accuracy per line) and, corrected, no effect is
    left to name."""
    from daq.run import run_test
    from daq.setup import parse_setup
    from daq.simlab import nominal_model
    from ssid.io import write_model
    from tui.results import analyse_run

    text = sine_setup(n_lines=6, reaction=True, sim_extra='sensitivity_error = { "load 14+Z" = 1.25 }')
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    run_test(setup, out=str(tmp_path / "run.h5"), sim=True, echo=lambda m: None)
    write_model(tmp_path / "structure.h5", nominal_model(setup, mounted=False))
    res = analyse_run(tmp_path / "run.h5", model_path=str(tmp_path / "structure.h5"))
    d = res.discrepancy
    assert d["reactions"]["applied"], res.notes
    cal = d["calibration"]
    assert cal["flagged"] and cal["reaction_gain"]["14+Z"] == pytest.approx(1.25, rel=0.01), cal["text"]
    assert all(g == pytest.approx(1.0, rel=0.01) for g in cal["output_gain"].values()), cal["output_gain"]
    assert cal["with_gains_corrected"]["effect"] == "none", cal["with_gains_corrected"]
    said = [n for n in res.notes if n.startswith("warning: channel gains explain")]
    assert len(said) == 1 and "load cell '14+Z' x 1.25" in said[0], res.notes
