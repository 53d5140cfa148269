"""The two channel lists of ``ssidlab tui`` (:class:`tui.app.LabApp` mixes them in): the Run
tab's, over the loaded setup's DOFs (the live plot), and the Results tab's, over the DOFs of
the FRF the results hold (the overlay and the exports). A choice in one is passed to the other
by DOF name: after another setup is loaded the same indices may name other DOFs.

Kept apart so that ``tui/app.py`` stays the screen's wiring. The methods use the app's widgets
(by id) and its state: ``setup``, ``results``, ``channel``, ``result_channel``.
"""

from __future__ import annotations

from rich.text import Text
from textual.widgets import Select

from .results import RunResults
from .results_pane import ResultsPane
from .setup_view import pair_options, same_pair

__all__ = ["ChannelListActions", "first_drive_point", "set_choices"]


def first_drive_point(outputs: list[str], inputs: list[str]) -> tuple[int, int]:
    """The channel a plot shows first: the first input's own response, else the first pair."""
    return (list(outputs).index(inputs[0]), 0) if inputs and inputs[0] in outputs else (0, 0)


def set_choices(select: Select, options: list[tuple[str, tuple[int, int]]], value: tuple[int, int] | None) -> None:
    """Fill a channel list and choose ``value`` (None: nothing chosen)."""
    select.set_options([(Text(label), v) for label, v in options])  # DOF names, not markup
    if value is not None:
        select.value = value


class ChannelListActions:
    """The channel lists' handlers and helpers of :class:`tui.app.LabApp`."""

    def on_select_changed(self, event: Select.Changed) -> None:
        """A channel chosen in one list: its plot, and the same DOFs in the other list. The
        live list indexes the loaded setup's DOFs, the Results list the results' FRF: after
        another setup is loaded the same indices may name other DOFs (passed on by name)."""
        if not isinstance(event.value, tuple):  # nothing chosen (Select.NULL) while options are set
            return
        if not event.select.is_attached:
            # Results shown just before a quit choose their channel: the choice is handled
            # while the app closes, its widgets gone (NoMatches crashed the quit).
            return
        value = tuple(event.value)
        frf = self.results.frf if self.results is not None else None
        setup = self.setup
        if event.select.id == "result-channel":
            self.result_channel = value
            self.query_one(ResultsPane).draw_overlay(self.results, value)
            if frf is not None and setup is not None:
                self._choose("#channel", same_pair(value, frf.outputs, frf.inputs, setup.outputs, setup.inputs))
        else:
            self.channel = value
            self._plot_dirty = True
            if frf is not None and setup is not None:
                self._choose("#result-channel",
                             same_pair(value, setup.outputs, setup.inputs, frf.outputs, frf.inputs))

    def _choose(self, selector: str, value: tuple[int, int] | None) -> None:
        """Choose ``value`` in a channel list, unless it is chosen already or None (not there)."""
        sel = self.query_one(selector, Select)
        if value is not None and sel.value != value:
            sel.value = value

    def _set_result_channels(self, results: RunResults | None) -> None:
        """The Results channel list from the FRF the results index (its own DOFs, whatever
        setup is loaded now), on the live plot's DOFs where the FRF has them."""
        sel = self.query_one("#result-channel", Select)
        if results is None:
            self.result_channel = None
            set_choices(sel, [], None)
            return
        frf, setup = results.frf, self.setup
        live = (same_pair(self.channel, setup.outputs, setup.inputs, frf.outputs, frf.inputs)
                if setup is not None and self.channel is not None else None)
        self.result_channel = live or first_drive_point(frf.outputs, frf.inputs)
        set_choices(sel, pair_options(frf.outputs, frf.inputs), self.result_channel)
