"""``ssidlab tui``: a keyboard-first Textual UI for a lab run (issue 8, first slice).

Three tabs:

* **Setup** - a setup TOML path, its channels and excitation (``daq.setup.load_setup``), the
  run file, a "simulated lab" switch; a bad file gives one line.
* **Run** - start / abort, a progress bar and the acquisition's log. The run is
  ``python -m ssidlab acquire SETUP [--sim] --out FILE`` in a subprocess, watched by a
  thread worker; abort sends it SIGINT (what Ctrl-C does: safe state, resumable file).
* **Results** - natural frequencies, damping ratios and MPC from
  ``identify_mck(read_frf(FILE))`` after a complete run.

No science or device logic lives here (see :mod:`tui.session`).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.widgets import (
    Button,
    DataTable,
    Footer,
    Header,
    Input,
    Label,
    ProgressBar,
    RichLog,
    Static,
    Switch,
    TabbedContent,
    TabPane,
)

from .session import (
    Acquisition,
    ModeRow,
    ProgressParser,
    RunOutcome,
    identify_file,
    run_file_state,
)

__all__ = ["LabApp"]


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).splitlines()) or type(exc).__name__
    return text


class LabApp(App):
    """The lab-run TUI. ``setup_path``, ``out`` and ``sim`` pre-fill the Setup tab."""

    TITLE = "ssidlab"
    SUB_TITLE = "lab run"
    CSS = """
    TabPane { padding: 0 1; }
    .row { height: 1; margin-bottom: 1; }
    .row Label { width: 14; }
    .row Input { width: 1fr; height: 1; border: none; padding: 0 1; }
    .row Switch { height: 1; border: none; padding: 0; width: 6; }
    #sim-state { width: 1fr; }
    #setup-error { color: $error; height: auto; }
    #excitation { height: auto; color: $text-muted; }
    #channels { height: 1fr; }
    #run-buttons { height: 1; margin-bottom: 1; }
    #run-buttons Button { margin-right: 1; height: 1; border: none; min-width: 14; }
    #run-status { height: auto; }
    #progress { height: 1; margin: 0 0 1 0; }
    #log { height: 1fr; border: round $panel; }
    #results-status { height: auto; }
    #modes { height: 1fr; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("f1", "show_tab('setup')", "Setup", priority=True),
        Binding("f2", "show_tab('run')", "Run", priority=True),
        Binding("f3", "show_tab('results')", "Results", priority=True),
        Binding("ctrl+l", "load", "Load", priority=True),
        Binding("f5", "start", "Start", priority=True),
        Binding("f8", "abort", "Abort", priority=True),
        Binding("ctrl+q", "quit", "Quit", priority=True),
    ]

    def __init__(self, setup_path: str | None = None, *, out: str | None = None, sim: bool = True) -> None:
        super().__init__()
        self._initial_path = setup_path or ""
        self._initial_out = out or ""
        self._initial_sim = sim
        self.setup = None  # daq.setup.TestSetup once loaded
        self.acquisition: Acquisition | None = None
        self.outcome: RunOutcome | None = None
        self.modes: list[ModeRow] = []
        self.results_message = ""

    # ------------------------------------------------------------------ layout
    def compose(self) -> ComposeResult:
        yield Header()
        with TabbedContent(initial="setup"):
            with TabPane("Setup F1", id="setup"):
                with Horizontal(classes="row"):
                    yield Label("Setup")
                    yield Input(self._initial_path, placeholder="SETUP.toml (Enter or Ctrl+L loads)",
                                id="setup-path")
                with Horizontal(classes="row"):
                    yield Label("Run file")
                    yield Input(self._initial_out, placeholder="RUN.h5 (default: the setup's [output] file)",
                                id="out-path")
                with Horizontal(classes="row"):
                    yield Label("Simulated lab")
                    yield Switch(self._initial_sim, id="sim")
                    yield Static(self._sim_text(self._initial_sim), id="sim-state")
                yield Static("", id="setup-error")
                yield Static("no setup loaded", id="excitation")
                yield DataTable(id="channels", cursor_type="row", zebra_stripes=True)
            with TabPane("Run F2", id="run"):
                with Horizontal(id="run-buttons"):
                    yield Button("Start (F5)", id="start", variant="success")
                    yield Button("Abort (F8)", id="abort", variant="error", disabled=True)
                yield Static("idle", id="run-status")
                yield ProgressBar(total=1.0, show_eta=False, id="progress")
                yield RichLog(id="log", max_lines=5000, wrap=False, markup=False)
            with TabPane("Results F3", id="results"):
                yield Static("no results yet: run a test first", id="results-status")
                yield DataTable(id="modes", cursor_type="row", zebra_stripes=True)
        yield Footer()

    def on_mount(self) -> None:
        ch = self.query_one("#channels", DataTable)
        ch.add_columns("name", "in", "dof", "quantity", "mV/unit", "range V", "coupl.")
        modes = self.query_one("#modes", DataTable)
        modes.add_columns("mode", "f [Hz]", "damping [%]", "MPC", "note")
        if self._initial_path:
            self.action_load()
        self.query_one("#setup-path", Input).focus()

    # ------------------------------------------------------------------ setup
    @staticmethod
    def _sim_text(on: bool) -> str:
        return " on: simulated instruments (--sim)" if on else " off: the setup's real instruments"

    def on_switch_changed(self, event: Switch.Changed) -> None:
        if event.switch.id == "sim":
            self.query_one("#sim-state", Static).update(self._sim_text(event.value))

    def action_show_tab(self, tab: str) -> None:
        self.query_one(TabbedContent).active = tab

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id in ("setup-path", "out-path"):
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
            err.update(f"error: {_one_line(exc)}")
            self.query_one("#excitation", Static).update("no setup loaded")
            return
        self.setup = setup
        err.update("")
        for c in setup.channels:
            table.add_row(c.name, str(c.input), c.dof, c.quantity, f"{c.sensitivity_mv_per_unit:g}",
                          f"{c.range_volt:g}", c.coupling)
        self.query_one("#excitation", Static).update(self._describe(setup))
        out = self.query_one("#out-path", Input)
        if not out.value.strip():
            out.value = setup.output_file

    @staticmethod
    def _describe(setup) -> str:
        head = (f"{setup.name}: {len(setup.channels)} channels, {len(setup.shakers)} shakers "
                f"({', '.join(s.dof for s in setup.shakers)}), DAQ {setup.daq.sample_rate_hz} S/s")
        if setup.excitation == "stepped_sine":
            s = setup.sine
            exc = (f"stepped sine {s.f_min_hz:g}-{s.f_max_hz:g} Hz, {s.n_lines} lines {s.spacing} "
                   f"x refine {s.refine}, force {s.force_n:g} N, accuracy {s.accuracy:g}")
        else:
            r = setup.random
            exc = (f"random ({r.kind}) {r.f_min_hz:g}-{r.f_max_hz:g} Hz, block {r.block_size}, "
                   f"{r.averages} averages, {r.window}, {r.estimator}, drive {r.drive_vpp:g} Vpp")
        lim = setup.limits
        return (f"{head}\n{exc}\nlimits: drive {lim.max_drive_vpp:g} Vpp, force {lim.max_force_n:g} N, "
                f"accel {lim.max_accel_m_per_s2:g} m/s2, reaction {lim.max_reaction_n:g} N; "
                f"min coherence {setup.min_coherence:g}")

    # ------------------------------------------------------------------ run
    @property
    def running(self) -> bool:
        return self.acquisition is not None and self.acquisition.running

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "start":
            self.action_start()
        elif event.button.id == "abort":
            self.action_abort()

    def _status(self, text: str) -> None:
        self.query_one("#run-status", Static).update(text)

    def action_start(self) -> None:
        if self.running:
            self.notify("a run is already in progress", severity="warning")
            return
        self.action_load()  # the file may have changed on disk since it was shown
        if self.setup is None:
            self.action_show_tab("setup")
            self.notify("load a valid setup first", severity="error")
            return
        out = self.query_one("#out-path", Input).value.strip() or self.setup.output_file
        out_path = Path(out)
        if not out_path.parent.is_dir():
            self.query_one("#setup-error", Static).update(
                f"error: {out}: directory {str(out_path.parent)!r} does not exist")
            self.action_show_tab("setup")
            return
        sim = self.query_one("#sim", Switch).value
        self.outcome = None
        self.modes = []
        self.results_message = ""
        self.query_one("#modes", DataTable).clear()
        self.query_one("#results-status", Static).update("run in progress...")
        self.query_one("#log", RichLog).clear()
        self.query_one("#progress", ProgressBar).update(total=1.0, progress=0.0)
        self.query_one("#start", Button).disabled = True
        self.query_one("#abort", Button).disabled = False
        self.acquisition = Acquisition(self.setup.source, out_path.resolve(), sim=sim)
        parser = ProgressParser.for_setup(self.setup)
        self._status(f"running: {out} ({'simulated lab' if sim else 'lab hardware'})")
        self.action_show_tab("run")
        self._log(f"$ ssidlab acquire {self.setup.source} --out {out}{' --sim' if sim else ''}")
        self._watch(self.acquisition, parser)

    def _log(self, line: str) -> None:
        self.query_one("#log", RichLog).write(line)

    def _progress(self, frac: float) -> None:
        self.query_one("#progress", ProgressBar).update(progress=frac)

    @work(thread=True, exclusive=True, group="acquire")
    def _watch(self, acq: Acquisition, parser: ProgressParser) -> None:
        """Worker thread: owns the acquisition subprocess until it has ended."""
        try:
            acq.start()
        except OSError as exc:
            self.call_from_thread(self._finished, RunOutcome(-1, False, acq.out, None), _one_line(exc))
            return
        for line in acq.lines():
            self.call_from_thread(self._log, line)
            frac = parser.feed(line)
            if frac is not None:
                self.call_from_thread(self._progress, frac)
        code = acq.wait()
        outcome = RunOutcome(code, acq.abort_requested, acq.out, run_file_state(acq.out))
        self.call_from_thread(self._finished, outcome, None)
        if outcome.complete:
            self.call_from_thread(self._results_status, "identifying M, C, K (SSID)...")
            try:
                rows, desc = identify_file(acq.out)
            except Exception as exc:  # noqa: BLE001 -- any identification failure is one line; the file is fine
                self.call_from_thread(self._show_results, [], f"identification failed: {_one_line(exc)}")
            else:
                self.call_from_thread(self._show_results, rows, desc)

    def _finished(self, outcome: RunOutcome, error: str | None) -> None:
        self.outcome = outcome
        text = outcome.summary() if error is None else f"could not start the run: {error}"
        self._status(text)
        self._log(text)
        if outcome.complete:
            self._progress(1.0)
        else:
            self.query_one("#results-status", Static).update(
                f"no results: {text}" + ("; resume with: ssidlab acquire --resume " + outcome.file
                                         if outcome.state and outcome.state != "complete" else ""))
        self.query_one("#start", Button).disabled = False
        self.query_one("#abort", Button).disabled = True

    def _results_status(self, text: str) -> None:
        self.query_one("#results-status", Static).update(text)

    def _show_results(self, rows: list[ModeRow], message: str) -> None:
        table = self.query_one("#modes", DataTable)
        table.clear()
        for r in rows:
            table.add_row(str(r.mode), f"{r.freq_hz:.3f}", f"{100 * r.damping_ratio:.3f}", f"{r.mpc:.3f}",
                          "" if r.in_band else "outside band")
        self.modes = rows
        self.results_message = message
        self._results_status(message)
        self.action_show_tab("results")

    def action_abort(self) -> None:
        if self.acquisition is not None and self.acquisition.abort():
            self._status("abort requested: stopping safely (SIGINT)...")
            self._log("abort requested: instruments to the safe state, run file kept resumable")
            self.query_one("#abort", Button).disabled = True
        else:
            self.notify("no run in progress", severity="warning")

    async def action_quit(self) -> None:
        self._stop_acquisition()
        await super().action_quit()

    def _stop_acquisition(self) -> None:
        if self.acquisition is not None:
            self.acquisition.shutdown()

    def on_unmount(self) -> None:
        self._stop_acquisition()


def main(setup_path: str | None = None, *, out: str | None = None, sim: bool = True) -> int:
    LabApp(setup_path, out=out, sim=sim).run()
    return 0
