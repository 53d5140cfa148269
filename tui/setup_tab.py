"""The Setup tab's actions of ``ssidlab tui`` (:class:`tui.app.LabApp` mixes them in): load a
setup file (Ctrl+L, Enter in a path field), create one from the simulated lab's example
(Ctrl+N), check the instruments (F4), and the simulated-lab switch.

Kept apart from the run and the results so that ``tui/app.py`` stays the screen's wiring. The
methods use the app's widgets (by id) and its state: ``setup``, ``model_error``, ``channel``
and ``running``.
"""

from __future__ import annotations

import os

from rich.markup import escape
from textual import work
from textual.widgets import DataTable, Input, Select, Static, Switch

from daq.check import check_lab

from .channel_lists import first_drive_point, set_choices
from .results import model_refusal
from .session import naming, one_line, printable
from .setup_view import (
    channel_options,
    channel_rows,
    checked_instrument_rows,
    configured_instrument_rows,
    describe_setup,
)

__all__ = ["CHECK_FAILED", "CHECK_PROMPT", "SetupTabActions", "typed_path"]

#: The instrument check's line before a check (F4) of the setup as loaded.
CHECK_PROMPT = "instruments (F4 checks the connections):"

#: The instrument check's line after a check that failed as a whole (its error is on the line above).
CHECK_FAILED = "instruments: the check failed (error above); nothing checked"


def typed_path(value: str) -> str:
    """A path as typed in a field: stripped, a leading ``~`` expanded; "" for an empty field."""
    text = value.strip()
    return os.path.expanduser(text) if text else ""


def plain_cells(row: tuple[str, ...]) -> tuple[str, ...]:
    """A table row shown as written: DataTable parses its string cells as markup, and the
    cells come from the setup file and the instruments' replies."""
    return tuple(escape(str(cell)) for cell in row)


def _new_file_refusal(path: str) -> str | None:
    """Why Ctrl+N must not write ``path``, or None. Only a path where nothing is, not even a
    symbolic link to a missing file (writing through it would create a file elsewhere)."""
    if not path:
        return "enter a path for the new setup file (Ctrl+N writes the example setup there)"
    shown = printable(path)
    if os.path.islink(path) and not os.path.exists(path):
        return f"{shown} is a symbolic link to a missing file: not written through"
    if os.path.lexists(path):
        return f"{shown} exists: not overwritten (Ctrl+L loads it)"
    return None


class SetupTabActions:
    """Mixin of :class:`tui.app.LabApp`: the Setup tab (F1)."""

    @staticmethod
    def _sim_text(on: bool) -> str:
        return " on: simulated instruments (--sim)" if on else " off: the setup's real instruments"

    def on_switch_changed(self, event: Switch.Changed) -> None:
        if event.switch.id == "sim":
            self.query_one("#sim-state", Static).update(self._sim_text(event.value))
            # Whether the [sim] table counts (and which lab a check's verdict was of) goes
            # with the switch: the setup is loaded again for the lab it now names.
            if not self.running and typed_path(self.query_one("#setup-path", Input).value):
                self.action_load()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id not in ("setup-path", "out-path", "model-path"):
            return
        if self.running:  # the screen shows the run's setup and instruments until it ends
            self.notify("a run is in progress: Enter loads the setup once it has ended", severity="warning")
            return
        self.action_load()

    def action_load(self) -> None:
        """Load the setup file in the path field and check the model file against it; with the
        switch on, also its ``[sim]`` table, which F4 and F5 then use."""
        from daq.setup import load_setup
        from daq.simlab import build_world
        from ssid.errors import InputError

        path = typed_path(self.query_one("#setup-path", Input).value)
        if not path:
            self._show_no_setup("error: enter a setup file path")
            return
        try:
            setup = load_setup(path)
            if self.query_one("#sim", Switch).value:
                # Refused as `ssidlab acquire --sim` refuses it before it creates the run file
                # (a bad [sim] table, a generator driving no shaker): one line naming the key.
                build_world(setup)
        except (InputError, OSError, ValueError) as exc:
            self._show_no_setup(f"error: {naming(path, exc)}")
            return
        self._show_setup(setup)

    def _show_no_setup(self, error: str) -> None:
        """No setup on the screen, ``error`` saying why: nothing shown is from another file."""
        self.setup = None
        self.model_error = None
        self.query_one("#setup-error", Static).update(error)
        self.query_one("#excitation", Static).update("no setup loaded")
        self.query_one("#channels", DataTable).clear()
        self._fill_instruments([])
        self.query_one("#check-status", Static).update(CHECK_PROMPT)

    def _show_setup(self, setup) -> None:
        self.setup = setup
        table = self.query_one("#channels", DataTable)
        table.clear()
        table.add_rows([plain_cells(r) for r in channel_rows(setup)])
        self.query_one("#excitation", Static).update(describe_setup(setup))
        out = self.query_one("#out-path", Input)
        if not out.value.strip():
            out.value = setup.output_file
        # The instruments as the file gives them: an earlier check's verdict is not theirs.
        self._fill_instruments(configured_instrument_rows(setup))
        self.query_one("#check-status", Static).update(CHECK_PROMPT)
        self._set_channels(channel_options(setup), setup)
        self.model_error = model_refusal(typed_path(self.query_one("#model-path", Input).value), setup)
        self.query_one("#setup-error", Static).update(f"error: {self.model_error}" if self.model_error else "")

    def _set_channels(self, options: list[tuple[str, tuple[int, int]]], setup) -> None:
        """The live plot's channel list, from the setup. Not the Results list: the results
        shown index their run's FRF, whose channels this setup may list otherwise."""
        if self.channel not in {v for _, v in options}:  # keep the engineer's choice across reloads
            self.channel = first_drive_point(setup.outputs, setup.inputs)
        set_choices(self.query_one("#channel", Select), options, self.channel)

    def action_new(self) -> None:
        """Create the setup file in the path field from the simulated lab's example, then load it."""
        from daq.simlab import example_setup_text

        path = typed_path(self.query_one("#setup-path", Input).value)
        refusal = _new_file_refusal(path)
        if refusal is None:
            try:
                # "x": never over a file, whatever appeared since the check above
                with open(path, "x", encoding="utf-8") as f:
                    f.write(example_setup_text())
            except (OSError, ValueError) as exc:
                refusal = naming(path, exc)
        if refusal is not None:
            self._new_refused(path, f"error: {refusal}")
            return
        self.action_load()
        self.notify(f"created {printable(path)} from the example setup: edit it for your lab, Ctrl+L reloads",
                    markup=False)

    def _new_refused(self, path: str, error: str) -> None:
        """Say why Ctrl+N wrote nothing; a setup shown stays only if it is the field's file."""
        if self.setup is not None and self.setup.source == path:
            self.query_one("#setup-error", Static).update(error)
        else:
            self._show_no_setup(error)

    def _fill_instruments(self, rows: list[tuple[str, str, str, str, str]]) -> None:
        t = self.query_one("#instruments", DataTable)
        t.clear()
        for r in rows:
            t.add_row(*plain_cells(r))

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
            "resetting latched amplifier faults, checking instruments..." if reset_faults
            else "checking instruments...")
        self._check(self.setup, self.query_one("#sim", Switch).value, reset_faults)

    @work(thread=True, exclusive=True, group="check")
    def _check(self, setup, sim: bool, reset_faults: bool = False) -> None:
        try:
            states = check_lab(setup, sim, reset_faults=reset_faults)
        except Exception as exc:  # noqa: BLE001 -- e.g. the simulated lab failing to start
            self._from_worker(self._show_line, "#setup-error", f"error: {one_line(exc)}")
            # The check has ended: "checking instruments..." stayed for good.
            self._from_worker(self._show_line, "#check-status", CHECK_FAILED)
            return
        rows, msg = checked_instrument_rows(states, sim)
        self._from_worker(self._fill_instruments, rows)
        self._from_worker(self._show_line, "#check-status", msg)

    def _show_line(self, selector: str, text: str) -> None:
        """Update a one-line Static (in the UI thread: workers never touch widgets)."""
        self.query_one(selector, Static).update(text)
