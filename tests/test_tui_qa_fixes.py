"""The TUI QA pass's findings, each driven through the app headless (Pilot, 80x24) and each
failing before its fix: a NUL byte in the run-file field, the live plot during the first
shaker's sweep, the amplifier panel after the run, an old run's results during a new run, the
Results channel list after another setup, a bad ``[sim]`` table, the status at 80x24, the
ETA after the run, and the abort's words before the run file exists."""

from __future__ import annotations

import asyncio

import pytest

pytest.importorskip("textual")

from textual.widgets import Static, TabbedContent
from tui_helpers import SIZE, small_setup

from tui.app import LabApp
from tui.session import LiveRun
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
