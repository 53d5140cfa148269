"""A miscalibrated accelerometer in the simulated lab, end to end: the run is acquired through
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
