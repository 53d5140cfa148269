"""The TUI QA pass's findings, each driven through the app headless (Pilot, 80x24) and each
failing before its fix: a NUL byte in the run-file field, the live plot during the first
shaker's sweep, the amplifier panel after the run, an old run's results during a new run, the
Results channel list after another setup, a bad ``[sim]`` table, the status at 80x24, the
ETA after the run, and the abort's words before the run file exists."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

pytest.importorskip("textual")

from textual.widgets import Input, Select, Static, Switch, TabbedContent
from tui_helpers import SIZE, abort_after_first_line, log_text, small_setup, wait_for

from tui.app import LabApp
from tui.results import RunResults
from tui.session import LiveRun, RunOutcome
from tui.widgets import FrfPlot


def shown(app: LabApp, selector: str) -> str:
    """The text a Static shows."""
    return str(app.query_one(selector, Static).render())


# ---------------------------------------------------------------------- 1: NUL byte in the run file
def test_a_nul_byte_in_the_run_file_field_is_one_error_line_not_a_crash(tmp_path):
    """F5 with a NUL byte in the run-file field: the Setup tab's error line names the file,
    as for a NUL byte in the setup field, and no run starts (it crashed the app)."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out="run\0.h5", sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f5")
            await pilot.pause()
            assert shown(app, "#setup-error") == "error: run\\x00.h5: embedded null byte"
            assert app.acquisition is None and app.query_one(TabbedContent).active == "setup"

    asyncio.run(go())


# ---------------------------------------------------------------------- 2: the first shaker's sweep
def test_the_live_plot_shows_the_first_shakers_sub_lines(tmp_path):
    """Two sub-lines of the first shaker, no complete line yet: the live plot is redrawn with
    them (docs/tui.md: the shaker's response per unit force); it stayed at "0 lines"."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause()  # the channel lists' changes from the load handled
            plot = app.query_one("#live-plot", FrfPlot)
            titles: list[str] = []
            real = plot.show_live
            plot.show_live = lambda title, *args: (titles.append(title), real(title, *args))
            app.live = LiveRun(app.setup.outputs, app.setup.inputs)
            app._redraw_live()  # nothing measured: not drawn
            o, i = app.channel
            for freq in (20.0, 25.0):
                y = [1e-3] * len(app.setup.outputs)
                app._event({"event": "sub_line", "shaker": i, "freq_hz": freq, "drive_vpp": 0.2, "ok": True,
                            "force_n": 1.0, "thd_max": 0.001, "reason": "", "Y_abs": y})
            app._redraw_live()
            assert titles and titles[-1].endswith(": 2 lines"), titles

    asyncio.run(go())


# ---------------------------------------------------------------------- 3: the amplifier panel at the end
AMP_ON = {"amplifiers": {"amp0": {"enabled": True, "interlock_closed": True, "fault": ""}}}


def test_after_an_abort_the_amplifier_panel_says_drives_off_not_on(tmp_path):
    """A simulated run aborted after its first line: its end confirmed the safe state (file
    state "interrupted"), and the panel says so instead of the last "amp0 on" read mid-run."""
    setup = small_setup(tmp_path, n_lines=40)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "cut.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await abort_after_first_line(pilot, app)
            assert app.outcome.state == "interrupted", log_text(app)
            panel = shown(app, "#inst-status")
            assert panel.startswith("run ended: drives off") and " on," not in panel, panel

    asyncio.run(go())


@pytest.mark.parametrize(("outcome", "expected"), [
    (RunOutcome(3, False, "r.h5", "stopped: amp0: heartbeat lost; safe state not confirmed: amp0: no reply"),
     "run ended: SAFE STATE NOT CONFIRMED - check the generators and amplifiers"),
    (RunOutcome(-9, True, "r.h5", "running"),  # killed: the file says nothing of its end
     "run ended: amplifier state unknown (its end did not confirm the safe state)"),
    (RunOutcome(0, False, "r.h5", "complete"),
     "run ended: drives off (outputs off, amplifiers disabled: confirmed at its end)"),
])
def test_the_amplifier_panel_claims_no_more_than_the_runs_end_reported(tmp_path, outcome, expected):
    """The panel after the run's last "amp0 on": confirmed off, not confirmed, or unknown."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "r.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause()
            app.live = LiveRun(app.setup.outputs, app.setup.inputs)
            app._event({"event": "instruments", "simulated": True, "identities": {}})
            app._event({"event": "sub_line", "shaker": 0, "freq_hz": 20.0, "drive_vpp": 0.2, "ok": False,
                        "reason": "limit", "instruments": AMP_ON})
            assert "amp0 on" in shown(app, "#inst-status")
            app._finished(outcome, None)
            assert shown(app, "#inst-status") == expected

    asyncio.run(go())


# ---------------------------------------------------------------------- 4: an old run's results
def test_an_old_runs_results_are_dropped_once_a_new_run_has_started(tmp_path, monkeypatch):
    """Run 1 completes; its analysis is held while F5 starts run 2 (refused at once: its run
    file cannot be created). Run 1's results, released then, must not show: run 2's "no
    results" stays, and the Run tab with it (they popped up and switched to Results). Four
    lines are too few to identify: run 1's "results" are its identification failure, which
    takes the same way to the screen as identified modes, in a fraction of the time."""
    import threading

    import tui.app

    setup = small_setup(tmp_path, n_lines=4)
    release, analysed, delivered = threading.Event(), threading.Event(), threading.Event()
    real_analyse = tui.app.analyse_run

    def held_analyse(*args, **kw):
        release.wait(30)
        try:
            return real_analyse(*args, **kw)
        finally:
            analysed.set()

    monkeypatch.setattr(tui.app, "analyse_run", held_analyse)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "run1.h5"), sim=True)
        real_call = app.call_from_thread

        def call_from_thread(*args, **kw):
            # The worker's next hand-over after its analysis: once it returns, the UI has
            # run (or dropped) the update with the results.
            was_analysed = analysed.is_set()
            try:
                return real_call(*args, **kw)
            finally:
                if was_analysed:
                    delivered.set()

        app.call_from_thread = call_from_thread
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f5")
            await wait_for(pilot, lambda: "identifying" in shown(app, "#results-status"), 60, "run 1's analysis")
            assert app.outcome.complete, log_text(app)
            app.query_one("#out-path", Input).value = "/proc/ssidlab-cannot-create.h5"
            await pilot.press("f5")
            await wait_for(pilot, lambda: app.outcome is not None, 60, "run 2's refusal")
            refused = shown(app, "#results-status")
            assert refused.startswith("no results: run refused"), refused
            release.set()
            await wait_for(pilot, delivered.is_set, 60, "run 1's results handed to the UI")
            assert app.results is None and shown(app, "#results-status") == refused
            assert app.query_one(TabbedContent).active == "run"

    asyncio.run(go())


# ---------------------------------------------------------------------- 5: Results channels after another setup
def _results_of(setup_path, run_path) -> RunResults:
    """Results of a run of ``setup_path`` without a run: the simulated lab's exact FRF on 8
    lines, the SSID model's FRF taken as the measured one (what the overlay and PNG need)."""
    from daq.setup import load_setup
    from daq.simlab import build_world

    setup = load_setup(setup_path)
    frf = build_world(setup).frf(np.geomspace(20.0, 1500.0, 8), outputs=setup.outputs, inputs=setup.inputs)
    return RunResults(run_path, frf, None, [], "run.h5: the old run", predicted=frf.H.copy())


def _labels(app: LabApp, selector: str) -> list[str]:
    return [str(label) for label, value in app.query_one(selector, Select)._options if isinstance(value, tuple)]


def test_the_results_channel_list_names_the_results_frf_not_a_setup_loaded_since(tmp_path):
    """Results shown, then another setup loaded whose first two responses are swapped: the
    Results list keeps the FRF's own labels, the overlay and the PNG follow the FRF's DOFs,
    and a choice there picks the same DOFs in the live list (indices of the new setup)."""
    setup = small_setup(tmp_path, n_lines=4)
    text = setup.read_text(encoding="utf-8")
    swapped = tmp_path / "swapped.toml"  # acc 1+Z now reads 2+Z and the other way round
    swapped.write_text(text.replace('dof = "1+Z"', 'dof = "@"').replace('dof = "2+Z"', 'dof = "1+Z"')
                       .replace('dof = "@"', 'dof = "2+Z"'), encoding="utf-8")
    results = _results_of(setup, tmp_path / "run.h5")
    frf = results.frf

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "next.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause()
            titles: list[str] = []
            overlay = app.query_one("#overlay", FrfPlot)
            real = overlay.show_overlay
            overlay.show_overlay = lambda title, *args: (titles.append(title), real(title, *args))
            app._show_results(results, results.description)
            app.query_one("#setup-path", Input).value = str(swapped)
            await pilot.press("f1", "ctrl+l")
            assert app.setup.outputs[:2] == ["2+Z", "1+Z"] and frf.outputs[:2] == ["1+Z", "2+Z"]
            assert _labels(app, "#result-channel") == [f"{o} / {i}" for i in frf.inputs for o in frf.outputs]
            assert _labels(app, "#channel")[0] == f"2+Z / {frf.inputs[0]}"  # the live list: the new setup
            app.query_one("#result-channel", Select).value = (0, 0)  # "1+Z / 11+Z" of the FRF
            await pilot.pause()
            assert titles[-1] == f"1+Z / {frf.inputs[0]}", titles
            assert app.channel == (1, 0)  # 1+Z of the new setup, in the live list
            await pilot.press("f3", "p")
            assert (tmp_path / "run_frf_1_Z_11_Z.png").is_file(), shown(app, "#export-status")

    asyncio.run(go())


# ---------------------------------------------------------------------- 6: a bad [sim] table; a failed check
def test_a_bad_sim_table_is_refused_at_load_when_the_run_will_use_the_simulated_lab(tmp_path):
    """With the switch on, F5 and F4 would use the simulated lab, which ``ssidlab acquire
    --sim`` refuses to build from this ``[sim]`` table: one error line at load (it loaded, and
    F4 then stood at "checking instruments..." for good). With the switch off the table is
    not used, and the setup loads."""
    good = small_setup(tmp_path, n_lines=4)
    bad = tmp_path / "badsim.toml"
    bad.write_text(good.read_text(encoding="utf-8").replace('structure = "payload"', "structure = 3"),
                   encoding="utf-8")
    error = f"error: {bad}: [sim] structure: must be a non-empty string, got 3"

    async def go() -> None:
        app = LabApp(str(bad), out=str(tmp_path / "run.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause()
            assert app.setup is None and shown(app, "#setup-error") == error
            await pilot.press("f5")
            assert app.acquisition is None and shown(app, "#setup-error") == error
            app.query_one("#sim", Switch).value = False  # the setup's real instruments
            await pilot.pause()
            assert app.setup is not None and shown(app, "#setup-error") == ""
            app.query_one("#sim", Switch).value = True
            await pilot.pause()
            assert app.setup is None and shown(app, "#setup-error") == error

    asyncio.run(go())


def test_a_check_that_fails_as_a_whole_says_so_on_the_check_line(tmp_path, monkeypatch):
    """F4 whose check raises (here the simulated lab failing to start): the check line no
    longer says "checking instruments..." for good."""
    import tui.setup_tab

    def failing_check(*args, **kw):
        raise OSError("simulated lab: port 5025 in use")

    monkeypatch.setattr(tui.setup_tab, "check_lab", failing_check)
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f4")
            await wait_for(pilot, lambda: "port 5025" in shown(app, "#setup-error"), 10, "the check's error")
            await pilot.pause()
            assert shown(app, "#check-status") == "instruments: the check failed (error above); nothing checked"

    asyncio.run(go())


# ---------------------------------------------------------------------- 7: the status at 80x24
LINK_DOWN = ("stopped: instrument lost (link down): gen0: cannot open serial port 'socket://127.0.0.1:1': "
             "Could not open port socket://127.0.0.1:1: [Errno 111] Connection refused")


def screen_lines(app: LabApp) -> list[str]:
    """The screen as text, one string a row."""
    return [strip.text for strip in app.screen._compositor.render_strips()]


def squeezed(text: str) -> str:
    """``text`` without whitespace: the words as they read, wherever the lines wrap."""
    return "".join(text.split())


async def _stopped(app: LabApp, pilot, tmp_path, state: str) -> None:
    """On the Run tab, the end of a run that stopped with exit 3 and the run file's ``state``."""
    await pilot.press("f2")
    app.live = LiveRun(app.setup.outputs, app.setup.inputs)
    app._finished(RunOutcome(3, False, str(tmp_path / "run.h5"), state), None)
    await pilot.pause()


def test_a_stops_whole_remedy_is_on_the_screen_at_80x24(tmp_path):
    """The status after a stop on an instrument not reached (five lines at 80 columns) ends
    with the remedy's last words, on screen with the log below it (it was cut at four)."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), sim=False)
        async with app.run_test(size=SIZE) as pilot:
            await _stopped(app, pilot, tmp_path, LINK_DOWN)
            status = shown(app, "#run-status")
            assert status.endswith(f"put that in {setup} first)"), status
            screen = "\n".join(screen_lines(app))
            assert squeezed(status) in squeezed(screen), screen  # every word, wrapped as it may
            log = app.query_one("#log").region
            assert log.height >= 3 and log.bottom <= SIZE[1] - 1, log  # above the footer
            assert "run ended before it reported" in screen  # the side panel still shown

    asyncio.run(go())


def test_a_status_longer_than_its_room_scrolls_by_keyboard(tmp_path):
    """A stop's status longer than the room it has scrolls: Tab reaches it, End shows its end."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), sim=False)
        async with app.run_test(size=SIZE) as pilot:
            long_state = LINK_DOWN + "".join(f"; detail {k}: the instrument said more" for k in range(20))
            await _stopped(app, pilot, tmp_path, long_state)
            status = app.query_one("#run-status").parent  # what scrolls it
            assert status.max_scroll_y > 0
            status.focus()
            await pilot.press("end")
            # End scrolls with an animation: on a loaded machine it had not ended at the next
            # pause (9.68 of 10 lines, once in CI).
            await wait_for(pilot, lambda: status.scroll_y == status.max_scroll_y, 5.0, "the status scrolled to its end")
            assert squeezed(f"{setup} first)") in squeezed("\n".join(screen_lines(app)))

    asyncio.run(go())


# ---------------------------------------------------------------------- 8: the ETA after the run
def eta_text(app: LabApp) -> str:
    """What the progress bar's ETA shows."""
    return str(app.query_one("#progress #eta").render())


async def eta_after(pilot, app: LabApp, seconds: float) -> str:
    """The ETA after ``seconds``: the bar recomputes it once a second."""
    await pilot.pause(seconds)
    return eta_text(app)


def test_the_eta_stands_still_while_paused_and_after_the_run_ends(tmp_path):
    """Progress 10 % then 20 % a second apart gives an ETA; it must not count down through a
    pause nor after the run's end (an abort), and counts on after the resume."""
    setup = small_setup(tmp_path, n_lines=4)

    async def go() -> None:
        app = LabApp(str(setup), out=str(tmp_path / "run.h5"), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f2")
            app.live = LiveRun(app.setup.outputs, app.setup.inputs)
            app._progress(0.1)
            await pilot.pause(1.1)
            app._progress(0.2)
            await pilot.pause()
            app._event({"event": "paused"})
            paused = await eta_after(pilot, app, 0.1)
            assert paused != "--:--:--" and await eta_after(pilot, app, 2.1) == paused
            app._event({"event": "resumed"})
            assert await eta_after(pilot, app, 2.1) < paused  # counting down again ("00:00:06" < "00:00:09")
            app._finished(RunOutcome(130, True, str(tmp_path / "run.h5"), "interrupted"), None)
            ended = await eta_after(pilot, app, 0.1)
            assert await eta_after(pilot, app, 2.1) == ended

    asyncio.run(go())


# ---------------------------------------------------------------------- 9: F8 before the run file exists
def test_an_abort_before_the_run_file_exists_does_not_say_it_is_kept(tmp_path, monkeypatch):
    """F8 while the run has not created its file yet (held there: its process only sleeps,
    as ``ssidlab acquire`` importing would): the log does not say the run file is kept
    resumable, and none is there. F8 after a measured line still says so."""
    import sys

    from tui.session import Acquisition

    setup = small_setup(tmp_path, n_lines=20)
    out = tmp_path / "run.h5"

    async def go() -> None:
        app = LabApp(str(setup), out=str(out), sim=True)
        async with app.run_test(size=SIZE) as pilot:
            with monkeypatch.context() as m:
                m.setattr(Acquisition, "argv", property(lambda self: [sys.executable, "-c",
                                                                      "import time; time.sleep(30)"]))
                await pilot.press("f5")
                await wait_for(pilot, lambda: app.running, 30, "the run's process")
                await pilot.press("f8")
                await wait_for(pilot, lambda: app.outcome is not None, 30, "the run to stop")
            log = log_text(app)
            assert "abort requested: instruments to the safe state, no run file created yet" in log, log
            assert "resumable" not in log and not out.exists()
            await abort_after_first_line(pilot, app)
            assert "abort requested: instruments to the safe state, run file kept resumable" in log_text(app)
            assert app.outcome.state == "interrupted"

    asyncio.run(go())


def test_a_rigid_body_pair_reads_rigid_in_the_mac_table_not_nan():
    """A free model's rigid-body pair has no percentage frequency error (``ssid.correlate``
    gives NaN: round-off over round-off); the results tab's MAC table printed "+nan"."""
    from ssid.correlate_models import correlate_models
    from ssid.io import Model
    from tui.results_pane import mac_row

    k = 1e4
    free = Model(M=np.diag([1.0, 2.0, 1.0]), C=None, K=k * np.array([[1.0, -1, 0], [-1, 2, -1], [0, -1, 1]]),
                 dofs=["1+Z", "2+Z", "3+Z"])
    rows = [mac_row(p) for p in correlate_models(free, free).summary["paired_modes"]]
    assert rows[0][2] == "rigid" and all("nan" not in cell for row in rows for cell in row), rows
    assert rows[1][2] == "+0.00" and rows[1][3] == "1.000"
