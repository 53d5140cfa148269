"""The Setup tab's actions of ``ssidlab tui`` (:class:`tui.app.LabApp` mixes them in): load a
setup file (Ctrl+L, Enter in a path field), create one from the simulated lab's example
(Ctrl+N), check the instruments (F4), and the simulated-lab switch.

Kept apart from the run and the results so that ``tui/app.py`` stays the screen's wiring. The
methods use the app's widgets (by id) and its state: ``setup``, ``channel`` and ``running``.
"""

from __future__ import annotations

from pathlib import Path

from textual import work
from textual.widgets import DataTable, Input, Select, Static, Switch

from daq.check import check_lab

from .session import one_line
from .setup_view import (
    channel_options,
    channel_rows,
    checked_instrument_rows,
    configured_instrument_rows,
    describe_setup,
)

__all__ = ["SetupTabActions"]


class SetupTabActions:
    """Mixin of :class:`tui.app.LabApp`: the Setup tab (F1)."""

    @staticmethod
    def _sim_text(on: bool) -> str:
        return " on: simulated instruments (--sim)" if on else " off: the setup's real instruments"

    def on_switch_changed(self, event: Switch.Changed) -> None:
        if event.switch.id == "sim":
            self.query_one("#sim-state", Static).update(self._sim_text(event.value))

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id in ("setup-path", "out-path", "model-path"):
            self.action_load()

    def action_load(self) -> None:
        from daq.setup import load_setup
        from ssid.errors import InputError

        path = self.query_one("#setup-path", Input).value.strip()
        err = self.query_one("#setup-error", Static)
        table = self.query_one("#channels", DataTable)
        table.clear()
        self.setup = None
        if not path:
            err.update("error: enter a setup file path")
            self.query_one("#excitation", Static).update("no setup loaded")
            return
        try:
            setup = load_setup(path)
        except (InputError, OSError, ValueError) as exc:
            err.update(f"error: {one_line(exc)}")
            self.query_one("#excitation", Static).update("no setup loaded")
            return
        self.setup = setup
        err.update("")
        table.add_rows(channel_rows(setup))
        self.query_one("#excitation", Static).update(describe_setup(setup))
        out = self.query_one("#out-path", Input)
        if not out.value.strip():
            out.value = setup.output_file
        self._fill_instruments(configured_instrument_rows(setup))
        options = channel_options(setup)
        if self.channel not in {v for _, v in options}:  # keep the engineer's choice across reloads
            self.channel = (setup.outputs.index(setup.inputs[0]), 0) if setup.inputs[0] in setup.outputs else (0, 0)
        for sel_id in ("#channel", "#result-channel"):
            sel = self.query_one(sel_id, Select)
            sel.set_options(options)
            sel.value = self.channel

    def action_new(self) -> None:
        """Create the setup file in the path field from the simulated lab's example, then load it."""
        from daq.simlab import example_setup_text

        path = Path(self.query_one("#setup-path", Input).value.strip() or "setup.toml")
        err = self.query_one("#setup-error", Static)
        if path.exists():
            err.update(f"error: {path} exists: not overwritten (Ctrl+L loads it)")
            return
        try:
            path.write_text(example_setup_text(), encoding="utf-8")
        except OSError as exc:
            err.update(f"error: {path}: {one_line(exc)}")
            return
        self.query_one("#setup-path", Input).value = str(path)
        self.action_load()
        self.notify(f"created {path} from the example setup: edit it for your lab, Ctrl+L reloads")

    def _fill_instruments(self, rows: list[tuple[str, str, str, str, str]]) -> None:
        t = self.query_one("#instruments", DataTable)
        t.clear()
        for r in rows:
            t.add_row(*r)

    def action_check(self, reset_faults: bool = False) -> None:
        """F4: check the instruments; Ctrl+F: reset the amplifiers' latched faults first (the
        amplifier refuses while a cause is present; nothing is switched on)."""
        if self.running:
            self.notify("the run owns the instruments; their state is on the Run tab", severity="warning")
            return
        self.action_load()
        if self.setup is None:
            self.notify("load a valid setup first", severity="error")
            return
        self.action_show_tab("setup")
        self.query_one("#check-status", Static).update(
            "resetting latched amplifier faults, checking instruments..." if reset_faults else "checking instruments...")
        self._check(self.setup, self.query_one("#sim", Switch).value, reset_faults)

    @work(thread=True, exclusive=True, group="check")
    def _check(self, setup, sim: bool, reset_faults: bool = False) -> None:
        try:
            states = check_lab(setup, sim, reset_faults=reset_faults)
        except Exception as exc:  # noqa: BLE001 -- e.g. a setup the simulated lab cannot build
            self._from_worker(self._show_line, "#setup-error", f"error: {one_line(exc)}")
            return
        rows, msg = checked_instrument_rows(states, sim)
        self._from_worker(self._fill_instruments, rows)
        self._from_worker(self._show_line, "#check-status", msg)

    def _show_line(self, selector: str, text: str) -> None:
        """Update a one-line Static (in the UI thread: workers never touch widgets)."""
        self.query_one(selector, Static).update(text)
