"""The Results tab of the lab-run TUI: identified modes, MAC, the discrepancy finding, the FRF
overlay and the export buttons, as one widget.

It only shows what :mod:`tui.results` computed; the app owns the run, the results and the
chosen channel, and calls :meth:`ResultsPane.show` when identification has finished.
"""

from __future__ import annotations

import numpy as np
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, DataTable, Select, Static

from .results import RunResults
from .widgets import FrfPlot

__all__ = ["EXPORT_KINDS", "ResultsPane", "mac_row"]

EXPORT_KINDS = ("hdf5", "uff", "png")


def mac_row(pair: dict) -> tuple[str, str, str, str]:
    """One MAC table row from a ``paired_modes`` entry of :func:`ssid.correlate_models.correlate_models`:
    test and analysis frequency (Hz), frequency error (%), MAC. A rigid-body pair has no
    percentage error (one of 0 Hz is round-off over round-off): its row says "rigid"."""
    err = "rigid" if pair.get("rigid") else f"{pair['freq_error_percent']:+.2f}"
    return (f"{pair['test_freq_hz']:.2f}", f"{pair['analysis_freq_hz']:.2f}", err, f"{pair['mac']:.3f}")


class ResultsPane(VerticalScroll):
    """Results of the last run. Children keep the ids the app and its tests query
    (``#results-status``, ``#modes``, ``#mac``, ``#discrepancy``, ``#result-channel``,
    ``#overlay``, ``#export-<kind>``, ``#export-status``); their styles are in the app's CSS,
    with the other tabs' (tui/app.tcss)."""

    def compose(self) -> ComposeResult:
        # markup=False: run states, errors, paths and the discrepancy finding are shown as written
        yield Static("no results yet: run a test first", id="results-status", markup=False)
        with Horizontal(id="tables"):
            yield DataTable(id="modes", cursor_type="row", zebra_stripes=True)
            yield DataTable(id="mac", cursor_type="row", zebra_stripes=True)
        yield Static("", id="discrepancy", markup=False)
        yield Select([], prompt="channel", id="result-channel", allow_blank=True)
        yield FrfPlot(id="overlay")
        with Horizontal(id="export-buttons"):
            yield Button("HDF5 h", id="export-hdf5", disabled=True)
            yield Button("UFF u", id="export-uff", disabled=True)
            yield Button("PNG p", id="export-png", disabled=True)
        yield Static("", id="export-status", markup=False)

    def on_mount(self) -> None:
        self.query_one("#modes", DataTable).add_columns("mode", "f [Hz]", "zeta %", "MPC")
        # MAC pairs the identified model's normal modes (undamped, of its M and K) with the
        # analysis model's: both frequencies shown, as the mode numbers differ from the table left.
        # Headed "M,K Hz", not "SSID Hz": in a reduced-order fit (a free test) they differ from
        # the roots on the left (311.07 Hz there, 310.88 Hz here on the free example).
        self.query_one("#mac", DataTable).add_columns("M,K Hz", "model Hz", "df %", "MAC")
        self.query_one("#overlay", FrfPlot).show_message("FRF overlay: after a run")

    def status(self, text: str) -> None:
        self.query_one("#results-status", Static).update(text)

    def export_status(self, text: str) -> None:
        self.query_one("#export-status", Static).update(text)

    def enable_exports(self, enabled: bool) -> None:
        for kind in EXPORT_KINDS:
            self.query_one(f"#export-{kind}", Button).disabled = not enabled

    def clear(self, text: str) -> None:
        """Empty tables and findings, with ``text`` as the status (a new run has started)."""
        for t in ("#modes", "#mac"):
            self.query_one(t, DataTable).clear()
        self.query_one("#discrepancy", Static).update("")
        self.query_one("#overlay", FrfPlot).show_message("FRF overlay: after a run")
        self.export_status("")
        self.status(text)

    def show(self, results: RunResults | None, message: str, channel: tuple[int, int] | None) -> None:
        """Fill the tab from ``results`` (None: identification failed, ``message`` says why)."""
        modes = self.query_one("#modes", DataTable)
        mac = self.query_one("#mac", DataTable)
        modes.clear()
        mac.clear()
        if results is not None:
            for r in results.modes:  # * marks a mode outside the measured band
                modes.add_row(f"{r.mode}{'' if r.in_band else '*'}", f"{r.freq_hz:.2f}",
                              f"{100 * r.damping_ratio:.2f}", f"{r.mpc:.2f}")
            for p in results.pairs:
                mac.add_row(*mac_row(p))
            notes = [n for n in results.notes if not n.startswith("discrepancy")]
            message = (message + ("; * outside the band" if any(not r.in_band for r in results.modes) else "")
                       + (f"\nMAC (right): undamped modes of the identified M, K vs the "
                          f"{results.model_source}" if results.pairs else "")
                       + "".join(f"\n{n}" for n in notes))
            self.query_one("#discrepancy", Static).update(results.discrepancy_text())
        self.status(message)
        self.draw_overlay(results, channel)

    def draw_overlay(self, res: RunResults | None, channel: tuple[int, int] | None) -> None:
        """Measured, SSID and model-with-effect FRF magnitudes of ``channel`` (output, input)."""
        if res is None or channel is None:
            return
        o, i = channel
        frf = res.frf
        if o >= frf.n_out or i >= frf.n_in:
            return
        H = np.where(frf.valid_mask()[:, o, i], np.abs(frf.H[:, o, i]), np.nan)
        curves = [("measured", H), ("SSID", np.abs(res.predicted[:, o, i]))]
        if res.updated is not None:
            curves.append(("model+effect", np.abs(res.updated[:, o, i])))
        self.query_one("#overlay", FrfPlot).show_overlay(f"{frf.outputs[o]} / {frf.inputs[i]}", frf.freq_hz, curves)
