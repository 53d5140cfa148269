"""The lab-run TUI (issue 8) driven headless through Textual's Pilot at 80x24: load a setup,
run a short simulated test to identified modes, abort a run mid-way."""

from __future__ import annotations

import argparse
import asyncio
import math

import h5py
import pytest

pytest.importorskip("textual")

from textual.widgets import DataTable, Input, Static, Switch, TabbedContent
from tui_helpers import EXAMPLE, SIZE, abort_after_first_line, log_text, small_setup, wait_for

from ssid.io import read_frf
from tui.app import LabApp
from tui.cli import add_tui_subcommand
from tui.session import Acquisition, ProgressParser, run_file_state


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
            await abort_after_first_line(pilot, app)
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
