"""The TUI audit's findings, each driven through the app headless (Pilot, 80x24): a refused run
says why and offers no F5, outside text is never markup, a bad model file is refused before
the run, Ctrl+N's edge cases, panels reset at F5, a quit right after F5 leaves no run, and
typed paths (``~``, a NUL byte)."""

from __future__ import annotations

import asyncio
import os

import numpy as np
import pytest

pytest.importorskip("textual")

from textual.widgets import DataTable, Input, Select, Static, Switch, TabbedContent
from tui_helpers import SIZE, abort_after_first_line, log_text, small_setup, wait_for

from ssid.io import Model, write_model
from tui.app import LabApp
from tui.results import RunResults
from tui.session import NO_INSTRUMENTS, NO_LINE, Acquisition, LiveRun, error_text
from tui.setup_tab import CHECK_PROMPT


def shown(app: LabApp, selector: str) -> str:
    return str(app.query_one(selector, Static).render())


def notes(app: LabApp) -> list[str]:
    return [str(n.message) for n in app._notifications]


# ---------------------------------------------------------------------- 1: a refused run says why
def test_a_refused_resume_shows_the_runs_error_and_offers_no_f5(tmp_path):
    """An aborted simulated run, then F5 (a) with the setup changed beyond what a resume may
    change and (b) with the switch off: ``ssidlab acquire`` refuses (exit 2) and the status
    line and Results tab carry its own error line, literally, without F5 as the remedy."""
    setup = small_setup(tmp_path, n_lines=20)
    good = setup.read_text(encoding="utf-8")
    out = tmp_path / "run.h5"

    async def refused(pilot, app: LabApp) -> str:
        await pilot.press("f5")
        await wait_for(pilot, lambda: app.outcome is not None, 60, "the refusal")
        assert app.outcome.returncode == 2 and app.outcome.state == "interrupted", log_text(app)
        status = shown(app, "#run-status")
        assert status.startswith("run refused (bad input): error: ") and "F5" not in status, status
        assert status in shown(app, "#results-status") and "F5" not in shown(app, "#results-status")
        return status

    async def go():
        app = LabApp(str(setup), out=str(out), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await abort_after_first_line(pilot, app, timeout=40)
            assert "F5 resumes the run file" in shown(app, "#run-status")
            setup.write_text(good.replace("n_lines = 20", "n_lines = 21"), encoding="utf-8")
            status = await refused(pilot, app)
            assert f"{setup}: differs from the setup of the run {out} in [stepped_sine]" in status, status
            setup.write_text(good, encoding="utf-8")
            app.query_one("#sim", Switch).value = False
            status = await refused(pilot, app)
            assert f"{out}: the run was measured on the simulated lab; resume it with --sim" in status, status

    asyncio.run(go())


def test_error_text_takes_the_commands_error_line():
    assert error_text("ssidlab acquire: error: a.toml: no such file") == "error: a.toml: no such file"
    assert error_text("ssidlab acquire: internal error: KeyError: 'x'") == "internal error: KeyError: 'x'"
    assert error_text("  shaker 0  20.000 Hz  error: 0.1 %") is None


# ---------------------------------------------------------------------- 2: outside text is not markup
def test_outside_text_is_shown_literally_and_never_crashes(tmp_path, monkeypatch):
    """An error naming ``[stepped_sine]`` keeps it; a path with ``[/]`` (load and Ctrl+N, whose
    notification names it) does not crash the app; bracketed setup and channel names and
    DOFs show as written in the excitation line, the channel table and the channel lists."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "n[").mkdir()  # so that "n[/].toml" is a file name a user can give
    good = small_setup(tmp_path, n_lines=4)
    text = good.read_text(encoding="utf-8")
    bad = tmp_path / "badval.toml"
    bad.write_text(text.replace("n_lines = 4", "n_lines = 1"), encoding="utf-8")
    odd = tmp_path / "odd.toml"
    odd.write_text(text.replace('name = "payload simulator', 'name = "[/][b]payload simulator')
                   .replace('name = "acc 1+Z"', 'name = "acc [/] 1+Z"').replace('dof = "1+Z"', 'dof = "1+Z[/]"'),
                   encoding="utf-8")

    async def go():
        app = LabApp()
        async with app.run_test(size=SIZE, notifications=True) as pilot:  # Ctrl+N's names the file
            field = app.query_one("#setup-path", Input)
            field.value = str(bad)
            await pilot.press("ctrl+l")
            assert "[stepped_sine] n_lines: must be" in shown(app, "#setup-error")
            field.value = "x[/].toml"
            await pilot.press("ctrl+l")
            assert shown(app, "#setup-error") == "error: x[/].toml: no such file"
            field.value = "n[/].toml"
            await pilot.press("ctrl+n")
            await pilot.pause(0.1)  # the notification is drawn
            assert app.setup is not None and (tmp_path / "n[/].toml").is_file()
            assert any("created n[/].toml" in n for n in notes(app))
            field.value = str(odd)
            await pilot.press("ctrl+l")
            # Its DOF "1+Z[/]" is not on the simulated payload: refused with the switch on, as
            # `ssidlab acquire --sim` refuses it, and the error names it as written.
            assert "'1+Z[/]'" in shown(app, "#setup-error") and app.setup is None, shown(app, "#setup-error")
            app.query_one("#sim", Switch).value = False  # a lab's own setup: loaded again
            await pilot.pause()
            assert shown(app, "#excitation").startswith("[/][b]payload simulator")
            channels = app.query_one("#channels", DataTable)
            rows = [channels.get_row_at(i) for i in range(channels.row_count)]
            assert any("[/] 1+Z" in str(r[0]) for r in rows)
            await pilot.press("f2")
            await pilot.click("#channel")
            await pilot.pause(0.1)  # the Run tab, its channel list ("1+Z[/] / 11+Z", ...) open and drawn
            assert app.query_one("#channel", Select).value == app.channel

    asyncio.run(go())


# ---------------------------------------------------------------------- 3: the model file, before the run
def test_a_bad_model_file_is_refused_at_load_and_f5(tmp_path):
    """A file that is no model, and a model with none of the setup's DOFs: one line naming
    the file at load, F5 refused; a model with the setup's DOFs and an empty field are fine."""
    setup = small_setup(tmp_path, n_lines=4)
    wrong = tmp_path / "wrong.h5"
    write_model(wrong, Model(np.eye(3), 1e6 * np.eye(3), None, ["a+X", "b+X", "c+X"]))

    async def go():
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), model=str(wrong))
        async with app.run_test(size=SIZE) as pilot:
            err = shown(app, "#setup-error")
            assert err.startswith(f"error: {wrong}: the model has none of the setup's ") and "\n" not in err, err
            await pilot.press("f5")
            assert app.acquisition is None and app.query_one(TabbedContent).active == "setup"
            assert "fix or clear the model file first" in notes(app)
            model_field = app.query_one("#model-path", Input)
            model_field.value = str(setup)  # a TOML file, no matrices
            await pilot.press("ctrl+l")
            assert shown(app, "#setup-error").startswith(f"error: {setup}: not a recognised matrix file")
            await pilot.press("f5")
            assert app.acquisition is None
            dofs = app.setup.outputs
            good = tmp_path / "good.h5"
            write_model(good, Model(np.eye(len(dofs)), 1e6 * np.eye(len(dofs)), None, list(dofs)))
            for value in (str(good), ""):  # the model is optional
                model_field.value = value
                await pilot.press("ctrl+l")
                assert app.model_error is None and shown(app, "#setup-error") == ""

    asyncio.run(go())


def test_a_model_that_is_not_physical_is_refused_at_load(tmp_path):
    """A model whose M has a negative mass, or is zero, or is singular with no C to damp it:
    one line naming the file and the reason at load, F5 refused (before, it was taken and the
    run ended with "MAC: ..." and "discrepancy workflow: ..." notes instead of results). The
    check is the discrepancy workflow's own (``ssid.discrepancy.check_model``): massless DOFs
    with a C are a usable model (lumped rotations), and are taken."""
    from daq.setup import load_setup

    setup = small_setup(tmp_path, n_lines=4)
    dofs = list(load_setup(setup).outputs)
    n = len(dofs)
    K, C = 1e6 * np.eye(n), 10.0 * np.eye(n)
    negative, massless = np.eye(n), np.eye(n)
    negative[1, 1], massless[1, 1] = -2.0, 0.0
    files = {}
    for name, M, damping in (("negative", negative, None), ("zero", np.zeros((n, n)), C),
                             ("massless_undamped", massless, None), ("massless_damped", massless, C)):
        files[name] = tmp_path / f"{name}.h5"
        write_model(files[name], Model(M, K, damping, dofs))
    refused = {
        "negative": "the model's M has the eigenvalue -2: not a mass matrix of a physical structure",
        "zero": "the model's M is zero: not a mass matrix of a physical structure",
        "massless_undamped": "M is not positive definite (a DOF without mass?), and modal damping, which "
                             "stands in for a model without C, needs a mass at every DOF: give the model its C",
    }

    async def go():
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), model=str(files["negative"]))
        async with app.run_test(size=SIZE) as pilot:
            model_field = app.query_one("#model-path", Input)
            for name, why in refused.items():
                model_field.value = str(files[name])
                await pilot.press("ctrl+l")
                assert shown(app, "#setup-error") == f"error: {files[name]}: {why}"
                await pilot.press("f5")
                assert app.acquisition is None and "fix or clear the model file first" in notes(app)
            model_field.value = str(files["massless_damped"])
            await pilot.press("ctrl+l")
            assert app.model_error is None and shown(app, "#setup-error") == ""

    asyncio.run(go())


def test_the_discrepancy_note_is_not_prefixed_twice(tmp_path):
    note = "discrepancy workflow: FRF output '1+Z' is not among the analysis model's DOFs"
    res = RunResults(tmp_path / "r.h5", None, None, [], "", notes=["MAC: x", note])
    assert res.discrepancy_text() == note
    assert RunResults(tmp_path / "r.h5", None, None, [], "").discrepancy_text() == \
        "discrepancy workflow: no analysis model"


# ---------------------------------------------------------------------- 4: Ctrl+N edge cases
def test_ctrl_n_refuses_an_empty_path_and_a_dangling_link_and_shows_no_other_setup(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    setup = small_setup(tmp_path, n_lines=4)
    link = tmp_path / "dangling.toml"
    os.symlink(tmp_path / "missing.toml", link)

    async def go():
        app = LabApp(str(setup))
        async with app.run_test(size=SIZE) as pilot:
            field = app.query_one("#setup-path", Input)
            await pilot.press("ctrl+n")  # on the loaded file itself: refused, and it stays shown
            assert "not overwritten" in shown(app, "#setup-error") and app.setup is not None
            field.value = "  "
            await pilot.press("ctrl+n")
            assert shown(app, "#setup-error") == ("error: enter a path for the new setup file "
                                                  "(Ctrl+N writes the example setup there)")
            assert not (tmp_path / "setup.toml").exists()
            # The setup shown was small.toml, not the field's: it is no longer shown.
            assert app.setup is None and shown(app, "#excitation") == "no setup loaded"
            assert app.query_one("#channels", DataTable).row_count == 0
            assert app.query_one("#instruments", DataTable).row_count == 0
            field.value = str(link)
            await pilot.press("ctrl+n")
            assert shown(app, "#setup-error") == f"error: {link} is a symbolic link to a missing file: " \
                                                 "not written through"
            assert not (tmp_path / "missing.toml").exists() and app.setup is None

    asyncio.run(go())


# ---------------------------------------------------------------------- 5: panels reset at F5
def test_f5_resets_the_line_and_instrument_panels_and_the_check_verdict(tmp_path):
    """After a run's last line and a check's verdict, F5 - here one the run refuses at once:
    its run file cannot be created - empties the side panels and the verdict, and the
    status names the run file's error."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go():
        app = LabApp(str(setup), out="/proc/ssidlab-cannot-create.h5", sim=True)
        async with app.run_test(size=SIZE) as pilot:
            app.live = LiveRun(app.setup.outputs, app.setup.inputs)
            app._event({"event": "sub_line", "shaker": 0, "freq_hz": 20.0, "drive_vpp": 0.2, "ok": False,
                        "reason": "earlier run", "instruments": {"amplifiers": {"amp0": {"enabled": True}}}})
            assert "earlier run" in shown(app, "#line-status") and "amp0 on" in shown(app, "#inst-status")
            app.query_one("#check-status", Static).update("instruments: all 4 answered and ready (simulated lab)")
            await pilot.press("f5")
            # The refusal may have ended the run already (a loaded machine), and then the
            # panel says so: either way the earlier run's "amp0 on" is gone.
            ended = app.outcome is not None
            assert shown(app, "#line-status") == NO_LINE
            assert shown(app, "#inst-status") == (app.live.ended_text(app.outcome) if ended else NO_INSTRUMENTS)
            assert shown(app, "#check-status") == CHECK_PROMPT
            await wait_for(pilot, lambda: app.outcome is not None, 60, "the refusal")
            status = shown(app, "#run-status")
            # refused before the run: the run file's directory takes no file
            assert app.outcome.returncode == 2 and "F5" not in status
            assert "/proc/ssidlab-cannot-create.h5: cannot write in directory '/proc'" in status, status
            assert shown(app, "#line-status") == NO_LINE
            assert shown(app, "#inst-status") == "run ended before it reported the instruments"

    asyncio.run(go())


# ---------------------------------------------------------------------- 6: a quit right after F5
def test_a_shutdown_that_has_begun_prevents_a_later_start(tmp_path):
    acq = Acquisition(small_setup(tmp_path, n_lines=4), tmp_path / "r.h5")
    acq.shutdown()
    assert acq.start() is False and acq.proc is None and not acq.running


def test_quit_right_after_start_leaves_no_run(tmp_path, monkeypatch):
    """The worker that starts the run is held until the app has gone (asyncio.run then waits
    for it: a late start ran the whole test after the UI had closed): it must start nothing."""
    import threading

    setup = small_setup(tmp_path, n_lines=4)
    app_gone = threading.Event()
    real_start = Acquisition.start

    def late_start(self):
        app_gone.wait(10)
        return real_start(self)

    monkeypatch.setattr(Acquisition, "start", late_start)
    held = {}

    async def go():
        app = LabApp(str(setup), out=str(tmp_path / "r.h5"), sim=True)
        async with app.run_test(size=SIZE):
            app.action_start()
            held["acq"] = app.acquisition
            await app.action_quit()
        app_gone.set()

    asyncio.run(go())  # returns once the worker has ended
    acq = held["acq"]
    try:
        assert acq.proc is None
    finally:
        if acq.proc is not None:
            acq.proc.kill()
            acq.proc.wait()


# ---------------------------------------------------------------------- 7: typed paths
def test_typed_paths_expand_home_and_name_the_file_on_a_nul_byte(tmp_path, monkeypatch):
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    small_setup(home, n_lines=4)

    async def go():
        app = LabApp()
        async with app.run_test(size=SIZE) as pilot:
            field = app.query_one("#setup-path", Input)
            field.value = "~/small.toml"
            await pilot.press("ctrl+l")
            assert app.setup is not None and app.setup.source == str(home / "small.toml")
            field.value = "~/new.toml"
            await pilot.press("ctrl+n")
            assert (home / "new.toml").is_file() and app.setup.source == str(home / "new.toml")
            field.value = "a\0b.toml"
            await pilot.press("ctrl+l")
            assert shown(app, "#setup-error") == "error: a\\x00b.toml: embedded null byte"

    asyncio.run(go())


# ---------------------------------------------------------------------- a random run's limit stop
def test_a_random_runs_limit_stop_says_to_start_a_new_run_not_to_resume(tmp_path):
    """A limit stops a continuous random run. The status said "F5 resumes the run file", but a
    resume may not change the drive and meets the same limit: it now says to lower drive_vpp
    and start a new run with another run file, as the command line does."""
    from test_daq_helpers import random_setup

    setup = tmp_path / "random.toml"
    setup.write_text(random_setup(kind="random", two=False, block=2048, settle=1, averages=4).replace(
        "drive_vpp = 0.5", "drive_vpp = 2.0") + "[limits]\nmax_accel_m_per_s2 = 8.0\n", encoding="utf-8")

    async def go():
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f5")
            await wait_for(pilot, lambda: app.outcome is not None, 60, "the limit to stop the run")
            assert app.outcome.returncode == 3 and "limit exceeded during random excitation" in app.outcome.state
            status = shown(app, "#run-status")
            assert "lower drive_vpp in [random]" in status and "start a new run" in status, status
            assert "F5 resumes" not in status, status

    asyncio.run(go())
