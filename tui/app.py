"""``ssidlab tui``: a keyboard-first Textual UI for a lab run (issue 8).

Three tabs:

* **Setup** - a setup TOML, its channels and excitation (``daq.setup.load_setup``), the run
  file, an optional analysis-model file, the "simulated lab" switch, and the instruments
  with their connection state and identity (F4: ``daq.check.check_instruments``).
* **Run** - start, pause (after the current line), resume, abort (drive to zero at once); a
  progress bar with ETA; the live FRF magnitude and coherence of a chosen channel as lines
  arrive; the current line's level, distortion and limit use; amplifier interlock and fault
  state; the acquisition's log. The run is ``python -m ssidlab acquire ... --events
  --control-stdin`` in a subprocess owned by a thread worker (:mod:`tui.session` says why).
* **Results** - identified frequencies and damping, MAC against the analysis model, an FRF
  overlay (measured, SSID model, model with the discrepancy workflow's effect), the
  discrepancy finding with the gap before and after, and exports (HDF5, UFF, PNG)
  (:mod:`tui.results_pane`).

No science or device logic lives here (:mod:`tui.session`, :mod:`tui.results`).
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import ClassVar

from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widgets import (
    Button,
    DataTable,
    Footer,
    Header,
    Input,
    Label,
    ProgressBar,
    RichLog,
    Select,
    Static,
    Switch,
    TabbedContent,
    TabPane,
)

from daq.safety import resume_remedy

from .channel_lists import ChannelListActions
from .results import RunResults, analyse_run, export_results
from .results_pane import ResultsPane
from .session import (
    NO_INSTRUMENTS,
    NO_LINE,
    Acquisition,
    LiveRun,
    ProgressParser,
    RunOutcome,
    error_text,
    one_line,
    parse_event,
    run_file_choice,
    run_file_state,
)
from .setup_tab import CHECK_PROMPT, SetupTabActions, typed_path
from .setup_view import instruments_in_use_rows, same_pair
from .widgets import FrfPlot, RunProgress

__all__ = ["LabApp"]


class LabApp(SetupTabActions, ChannelListActions, App):
    """The lab-run TUI. ``setup_path``, ``out``, ``model`` and ``sim`` pre-fill the Setup tab."""

    ENABLE_COMMAND_PALETTE = False  # every action has its key; the footer needs the room
    TITLE = "ssidlab"
    SUB_TITLE = "lab run"
    CSS_PATH = "app.tcss"  # every tab's styles, the Results pane's included
    BINDINGS: ClassVar[list[Binding]] = [
        # The tab titles carry F1-F3; the footer keeps its width for what applies now.
        Binding("f1", "show_tab('setup')", "Setup", priority=True, show=False),
        Binding("f2", "show_tab('run')", "Run", priority=True, show=False),
        Binding("f3", "show_tab('results')", "Results", priority=True, show=False),
        Binding("ctrl+l", "load", "Load", priority=True),
        Binding("ctrl+n", "new", "New", priority=True),
        Binding("f4", "check", "Check", priority=True),
        Binding("ctrl+f", "check(True)", "Reset faults", priority=True, show=False),
        Binding("f5", "start", "Start", priority=True),
        # Only after a resume stopped on another instrument than the run's last session's.
        Binding("ctrl+r", "start(True)", "Resume, replaced", priority=True, show=False),
        Binding("f6", "pause", "Pause", priority=True),
        Binding("f7", "resume", "Resume", priority=True),
        Binding("f8", "abort", "Abort", priority=True),
        Binding("h", "export('hdf5')", "HDF5"),
        Binding("u", "export('uff')", "UFF"),
        Binding("p", "export('png')", "PNG"),
        Binding("ctrl+q", "quit", "Quit", priority=True),
    ]

    def __init__(self, setup_path: str | None = None, *, out: str | None = None, sim: bool = True,
                 model: str | None = None) -> None:
        super().__init__()
        self._initial = {"setup": setup_path or "", "out": out or "", "model": model or ""}
        self._initial_sim = sim
        self.setup = None  # daq.setup.TestSetup once loaded
        self.model_error: str | None = None  # why the model file cannot serve the loaded setup
        self.acquisition: Acquisition | None = None
        self.outcome: RunOutcome | None = None
        self.live: LiveRun | None = None
        self.results: RunResults | None = None
        self.results_message = ""
        self.pause_pending = False
        self.channel: tuple[int, int] | None = None  # (output, input) of the setup in the live plot; set at load
        self.result_channel: tuple[int, int] | None = None  # (output, input) of the results' FRF
        self._plot_dirty = False

    # ------------------------------------------------------------------ layout
    def compose(self) -> ComposeResult:
        yield Header()
        with TabbedContent(initial="setup"):
            with TabPane("Setup F1", id="setup"), VerticalScroll():
                for label, key, hint in (("Setup", "setup", "SETUP.toml (Enter/Ctrl+L loads, Ctrl+N creates)"),
                                         ("Run file", "out", "RUN.h5 (default: the setup's [output] file)"),
                                         ("Model", "model", "optional: model file (.h5/.mat/.op4)")):
                    with Horizontal(classes="row"):
                        yield Label(label)
                        yield Input(self._initial[key], placeholder=hint, id=f"{key}-path")
                with Horizontal(classes="row"):
                    yield Label("Simulated lab")
                    yield Switch(self._initial_sim, id="sim")
                    yield Static(self._sim_text(self._initial_sim), id="sim-state", markup=False)
                # markup=False wherever text from outside is shown (paths, errors, setup names,
                # run states): "[stepped_sine]" in an error is words, and "x[/].toml" no crash.
                yield Static("", id="setup-error", markup=False)
                yield Static("no setup loaded", id="excitation", markup=False)
                yield Static(CHECK_PROMPT, id="check-status", markup=False)
                yield DataTable(id="instruments", cursor_type="row", zebra_stripes=True)
                yield DataTable(id="channels", cursor_type="row", zebra_stripes=True)
            with TabPane("Run F2", id="run"):
                with Horizontal(id="run-buttons"):
                    yield Button("Start F5", id="start", variant="success")
                    yield Button("Pause F6", id="pause", disabled=True)
                    yield Button("Resume F7", id="resume", disabled=True)
                    yield Button("Abort F8", id="abort", variant="error", disabled=True)
                # In a scroll container (focusable: Tab, arrows, End) for a stop's long remedy.
                with VerticalScroll(id="run-status-box"):
                    yield Static("idle", id="run-status", markup=False)
                yield RunProgress(total=1.0, show_eta=True, id="progress")
                with Horizontal(id="live"):
                    yield FrfPlot(id="live-plot")
                    with Vertical(id="side"):
                        yield Select([], prompt="channel", id="channel", allow_blank=True)
                        yield Static(NO_LINE, id="line-status", markup=False)
                        yield Static(NO_INSTRUMENTS, id="inst-status", markup=False)
                yield RichLog(id="log", max_lines=5000, wrap=False, markup=False)
            with TabPane("Results F3", id="results"):
                yield ResultsPane(id="results-scroll")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one("#channels", DataTable).add_columns(
            "name", "in", "dof", "quantity", "mV/unit", "range V", "coupl.")
        self.query_one("#instruments", DataTable).add_columns("instrument", "kind", "address", "state", "identity")
        self.query_one("#live-plot", FrfPlot).show_message("live FRF: start a run (F5)")
        self.set_interval(0.25, self._redraw_live)
        if self._initial["setup"]:
            self.action_load()
        self.query_one("#setup-path", Input).focus()

    # ------------------------------------------------------------------ actions: which apply now
    def check_action(self, action: str, parameters: tuple) -> bool | None:
        """Which keys apply now: the footer shows only those (an 80-column footer has room
        for about six), so the hints always say what can be done next."""
        try:
            tab = self.query_one(TabbedContent).active
        except Exception:  # noqa: BLE001 -- before the layout exists
            return True
        if action == "check" and parameters == (True,):  # Ctrl+F: from any tab, after a trip
            return not self.running
        if action in ("load", "check", "new"):
            return tab == "setup" and not self.running
        if action == "start":
            return not self.running
        if action == "pause":
            return self.running and not self.pause_pending
        if action == "resume":
            return self.running and self.pause_pending
        if action == "abort":
            return self.running
        if action == "export":
            return tab == "results" and self.results is not None
        return True

    def _refresh_controls(self) -> None:
        running = self.running
        self.query_one("#start", Button).disabled = running
        self.query_one("#pause", Button).disabled = not running or self.pause_pending
        self.query_one("#resume", Button).disabled = not (running and self.pause_pending)
        self.query_one("#abort", Button).disabled = not running
        self.query_one(ResultsPane).enable_exports(self.results is not None)
        self.refresh_bindings()

    # ------------------------------------------------------------------ tabs
    def action_show_tab(self, tab: str) -> None:
        self.query_one(TabbedContent).active = tab
        pane = self.query_one(f"#{tab}", TabPane)
        # Keys must act on the tab in view: move the focus into it unless it is there already.
        if self.focused is None or pane not in self.focused.ancestors_with_self:
            for widget in pane.query("*"):
                if widget.focusable:
                    widget.focus()
                    break
        self.refresh_bindings()

    def on_tabbed_content_tab_activated(self, event: TabbedContent.TabActivated) -> None:
        # A run's results switch to their tab when the analysis ends, which may be while the
        # app is closing: the screens are gone by the time this message is handled, and
        # refreshing the bindings then raised ScreenStackError on quit.
        if self.screen_stack:
            self.refresh_bindings()

    # ------------------------------------------------------------------ run
    @property
    def running(self) -> bool:
        return self.acquisition is not None and self.acquisition.running

    def on_button_pressed(self, event: Button.Pressed) -> None:
        bid = event.button.id or ""
        if bid in ("start", "pause", "resume", "abort"):
            getattr(self, f"action_{bid}")()
        elif bid.startswith("export-"):
            self.action_export(bid.removeprefix("export-"))

    def _status(self, text: str) -> None:
        self.query_one("#run-status", Static).update(text)

    def action_start(self, new_instruments: bool = False) -> None:
        """F5: start the run, or resume its unfinished run file; Ctrl+R: resume it with an
        instrument that answers as another than in the run's last session (replaced)."""
        if self.running:
            self.notify("a run is already in progress", severity="warning")
            return
        self.action_load()  # the file may have changed on disk since it was shown
        if self.setup is None or self.model_error:
            self.action_show_tab("setup")
            self.notify("load a valid setup first" if self.setup is None else "fix or clear the model file first",
                        severity="error")
            return
        out = typed_path(self.query_one("#out-path", Input).value) or self.setup.output_file
        refusal, resume = run_file_choice(out)
        if refusal is not None:
            self.query_one("#setup-error", Static).update(f"error: {refusal}")
            self.action_show_tab("setup")
            return
        if new_instruments and not resume:
            self.notify("Ctrl+R resumes an unfinished run file with replaced instruments; F5 starts a run",
                        severity="warning")
            return
        sim = self.query_one("#sim", Switch).value
        self.outcome = None
        self.results = None
        self.results_message = ""
        self.pause_pending = False
        self.live = LiveRun(self.setup.outputs, self.setup.inputs)
        self._set_result_channels(None)  # the last run's FRF is no longer shown
        # The side panels said what the last run's last line and instruments did.
        self.query_one("#line-status", Static).update(NO_LINE)
        self.query_one("#inst-status", Static).update(NO_INSTRUMENTS)
        self.query_one(ResultsPane).clear("run in progress...")
        self.query_one("#log", RichLog).clear()
        self.query_one("#run", TabPane).remove_class("-stopped")  # the status is short again
        progress = self.query_one("#progress", RunProgress)
        progress.update(total=1.0, progress=0.0)
        progress.go()
        self.acquisition = Acquisition(self.setup.source, Path(out).resolve(), sim=sim, resume=resume,
                                       new_instruments=new_instruments)
        parser = ProgressParser.for_setup(self.setup)
        self._status(f"{'resuming' if resume else 'running'}: {out} ({'simulated lab' if sim else 'lab hardware'})")
        self._log(f"$ ssidlab acquire {self.setup.source} {'--resume' if resume else '--out'} {out}"
                  f"{' --sim' if sim else ''}{' --new-instruments' if new_instruments else ''}")
        self._watch(self.acquisition, parser, self.setup, sim, typed_path(self.query_one("#model-path", Input).value))
        self.action_show_tab("run")
        self._refresh_controls()

    def _log(self, line: str) -> None:
        self.query_one("#log", RichLog).write(line)

    def _progress(self, frac: float) -> None:
        self.query_one("#progress", ProgressBar).update(progress=frac)

    def _event(self, ev: dict) -> None:
        """One run event, in the UI thread."""
        live = self.live
        if live is None:
            return
        kind = live.feed(ev)
        # A stepped-sine sub-line is on the plot too (a shaker's response per unit force,
        # until every shaker has measured the line): the first shaker's sweep left it empty.
        if kind in ("line", "spectrum", "sub_line"):
            self._plot_dirty = True
        if kind == "instruments":
            self._fill_instruments(instruments_in_use_rows(ev, self.setup))
        if kind == "paused":
            self.query_one("#progress", RunProgress).hold()  # nothing measured until F7
            self.pause_pending = True
            self._status("PAUSED: generator outputs off, amplifiers disabled - F7 resumes, F8 aborts")
        elif kind == "resumed":
            self.query_one("#progress", RunProgress).go()
            self.pause_pending = False
            self._status("running (resumed)")
        self.query_one("#line-status", Static).update(live.line_text())
        self.query_one("#inst-status", Static).update(live.instrument_text())
        self._refresh_controls()

    def _redraw_live(self) -> None:
        # The timer may tick once more while the app closes, its widgets gone: a line that
        # arrived just before a quit then made the redraw raise NoMatches.
        if not self._plot_dirty or self.live is None or self.setup is None or not self.query("#live-plot"):
            return
        self._plot_dirty = False
        live, setup = self.live, self.setup
        o, i = self.channel
        name = f"{setup.outputs[o]} / {setup.inputs[i]}" if o < len(setup.outputs) and i < len(setup.inputs) else ""
        # The curves index the run's setup, the list the setup loaded since (the same by name).
        pair = same_pair(self.channel, setup.outputs, setup.inputs, live.outputs, live.inputs)
        if pair is None:
            self.query_one("#live-plot", FrfPlot).show_live(f"{name}: not measured in the last run", [], [], [])
            return
        f, h, c = live.curve(*pair)
        self.query_one("#live-plot", FrfPlot).show_live(f"{name}: {len(f)} lines", f, h, c)

    def _from_worker(self, update, *args) -> None:
        """Run the UI update ``update(*args)`` from a worker thread, or drop it once the app is
        closing. A worker outlives a quit (a run's analysis takes seconds), and by the time its
        update runs the widgets it fills may be gone: filling the results pane then raised
        NoMatches, and the tab switch after it ScreenStackError (both seen on a quit right
        after a run)."""
        def if_running() -> None:
            if self.is_running:
                update(*args)

        try:
            self.call_from_thread(if_running)
        except RuntimeError:  # the app has stopped: no event loop to run it on
            pass

    def _from_run(self, acq: Acquisition, update, *args) -> None:
        """As :meth:`_from_worker`, for the worker of the run ``acq``: dropped once another run
        has started. F5 is offered as soon as a run's process has ended, while its worker
        still hands on its last lines and computes its results (seconds): an old run's
        results then showed during the new run, over its panels and its status."""
        def if_current() -> None:
            if self.acquisition is acq:
                update(*args)

        self._from_worker(if_current)

    @work(thread=True, exclusive=True, group="acquire")
    def _watch(self, acq: Acquisition, parser: ProgressParser, setup, sim: bool, model_path: str) -> None:
        """Worker thread: owns the acquisition subprocess until it has ended."""
        try:
            if not acq.start():  # the app is closing: nothing started, nothing to stop
                return
        except OSError as exc:
            self._from_run(acq, self._finished, RunOutcome(-1, False, acq.out, None), one_line(exc))
            return
        error = None
        for line in acq.lines():
            ev = parse_event(line)
            if ev is not None:
                self._from_run(acq, self._event, ev)
                continue
            self._from_run(acq, self._log, line)
            error = error_text(line) or error
            frac = parser.feed(line)
            if frac is not None:
                self._from_run(acq, self._progress, frac)
        code = acq.wait()
        outcome = RunOutcome(code, acq.abort_requested, acq.out, run_file_state(acq.out), error)
        self._from_run(acq, self._finished, outcome, None)
        if outcome.complete and self.acquisition is acq:  # no results for a run no longer shown
            self._from_run(acq, self._results_status, "identifying M, C, K (SSID), correlating, "
                                                      "looking for the discrepancy...")
            try:
                results = analyse_run(acq.out, setup, sim=sim, model_path=model_path or None)
            except Exception as exc:  # noqa: BLE001 -- any identification failure is one line; the file is fine
                self._from_run(acq, self._show_results, None, f"identification failed: {one_line(exc)}")
            else:
                self._from_run(acq, self._show_results, results, results.description)

    def _finished(self, outcome: RunOutcome, error: str | None) -> None:
        self.outcome = outcome
        self.query_one("#progress", RunProgress).hold()  # nothing more to count down to
        self.pause_pending = False
        text = outcome.summary() if error is None else f"could not start the run: {error}"
        self._status(text)
        self._log(text)
        if self.live is not None:  # the amplifiers' last state read during the run holds no more
            self.query_one("#inst-status", Static).update(self.live.ended_text(outcome))
        if outcome.complete:
            self._progress(1.0)
        else:
            resumable = outcome.resumable
            how = "F5 resumes the run file"
            # F5 re-reads the setup file, and a resume may change the channels' range_volt and
            # the instruments' addresses (daq.resume): the same setup would meet the same fault.
            sim = self.acquisition is not None and self.acquisition.sim
            remedy = resume_remedy(outcome.state, sim) if resumable else None
            if remedy == "range_volt" and self.setup is not None:
                how += f" (a range too small for the level: raise its range_volt in {self.setup.source} first)"
            elif remedy == "address" and self.setup is not None:
                how += (f" (an instrument not reached: if it answers at another address now, "
                        f"put that in {self.setup.source} first)")
            elif remedy == "reset_faults":
                how += " (an amplifier's trip is latched: once its cause is gone, Ctrl+F resets it first)"
            elif remedy == "new_instruments":
                how += " after checking the addresses; Ctrl+R resumes with the instruments that answer now (replaced)"
            elif remedy == "new_run":
                how = ("a resume would drive as hard and exceed the limit again: lower drive_vpp in [random] "
                       "(or set limits the test allows) and start a new run, with another run file")
            self.query_one(ResultsPane).status(f"no results: {text}" + (f"; {how}" if resumable else ""))
            if resumable:
                self._status(f"{text} - {how}")
            # A stop's why and remedy run to several lines: the status takes room from the
            # log (its lines are in the status) and scrolls beyond (tui/app.tcss).
            self.query_one("#run", TabPane).add_class("-stopped")
        self._refresh_controls()

    def _results_status(self, text: str) -> None:
        self.query_one(ResultsPane).status(text)

    def _show_results(self, results: RunResults | None, message: str) -> None:
        self.results = results
        self.results_message = message
        self._set_result_channels(results)
        self.query_one(ResultsPane).show(results, message, self.result_channel)
        self._refresh_controls()
        self.action_show_tab("results")

    def action_pause(self) -> None:
        if self.acquisition is not None and self.acquisition.pause():
            self.pause_pending = True
            self._status("pause requested: finishing the current line, then outputs off and amplifiers "
                         "disabled...")
            self._log("pause requested")
        else:
            self.notify("no run in progress", severity="warning")
        self._refresh_controls()

    def action_resume(self) -> None:
        if self.acquisition is not None and self.acquisition.resume():
            self._log("resume requested")
            if self.live is not None and not self.live.paused:
                self.pause_pending = False  # asked back before the line had finished
                self._status("running")
        else:
            self.notify("no run in progress", severity="warning")
        self._refresh_controls()

    def action_abort(self) -> None:
        acq = self.acquisition
        if acq is not None and acq.abort():
            self._status("abort requested: stopping safely (SIGINT)...")
            # Right after F5 the run may not have created its file yet: none to keep then.
            kept = "run file kept resumable" if Path(acq.out).exists() else "no run file created yet"
            self._log(f"abort requested: instruments to the safe state, {kept}")
            self.query_one("#abort", Button).disabled = True
        else:
            self.notify("no run in progress", severity="warning")

    def action_export(self, kind: str) -> None:
        if self.results is None:
            self.notify("no results to export yet", severity="warning")
            return
        try:
            paths = export_results(self.results, kind, *(self.result_channel or (0, 0)))
        except Exception as exc:  # noqa: BLE001 -- an export failure is one line; nothing else is lost
            self.query_one(ResultsPane).export_status(f"export {kind} failed: {one_line(exc)}")
            return
        self.query_one(ResultsPane).export_status("wrote " + ", ".join(str(p) for p in paths))

    async def action_quit(self) -> None:
        await self._stop_acquisition()
        await super().action_quit()

    async def _stop_acquisition(self) -> None:
        if self.acquisition is not None:
            # Waited for in a thread, never on this event loop: the worker reading the run's
            # output hands each line to this loop and waits for it (call_from_thread), so a
            # loop blocked in the wait (up to the 15 s grace) also stops that reader, and the
            # screen freezes while the run reaches its safe state.
            await asyncio.to_thread(self.acquisition.shutdown)

    async def on_unmount(self) -> None:
        await self._stop_acquisition()


def main(setup_path: str | None = None, *, out: str | None = None, sim: bool = True, model: str | None = None) -> int:
    LabApp(setup_path, out=out, sim=sim, model=model).run()
    return 0
