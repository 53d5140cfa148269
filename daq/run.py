"""A whole acquisition: run file, instruments, the excitation, and every exit path safe.

:func:`run_test` is what ``ssidlab acquire`` calls. Whatever happens - the run completes,
a limit or an instrument fault stops it, Ctrl-C, SIGTERM or a bug - the instruments are put
in the safe state (all generator outputs off, all amplifiers disabled, acquisition stopped)
before the function returns or raises, and the run file holds every completed line:

* complete: the run file is replaced by the compact FRF file (plus ``/acq``), and the
  FRFs are exported to UFF 58 if ``[output] uff`` is set (beside a run file given by
  ``out``, with its name);
* stopped, interrupted or failed: ``/acq`` attribute ``state`` says why and the file can
  be continued with ``ssidlab acquire --resume FILE``.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import os
import platform
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from drivers.errors import InstrumentError
from ssid.errors import InputError

from .control import RunControl, RunEvents, clear_interrupts, latching_interrupt_handler
from .coupling import coupling_attrs
from .resume import instruments_not_the_same, range_changes, setup_changes_on_resume, setup_in_effect
from .rig import InstrumentRig, Rig
from .safety import NOT_THE_SAME_INSTRUMENTS, SAFE_STATE_NOT_CONFIRMED, STATE_MAX_CHARS, RunStopped, describe_fault
from .setup import TestSetup
from .storage import RunFile
from .thread_stacks import thread_stacks, write_to_stderr

__all__ = ["run_test"]

log = logging.getLogger(__name__)


def _version() -> str:
    try:
        from ssidlab import __version__

        return str(__version__)
    except Exception:  # pragma: no cover - version is informative only
        return "unknown"


@contextlib.contextmanager
def _interrupts_deferred():
    """Hold SIGINT / SIGTERM back while the run reaches the safe state and closes its file.

    A second Ctrl-C (an impatient operator, or a UI that both signals and closes the run's
    input) would otherwise raise inside the cleanup and leave a drive on or the file's state
    unwritten. Yields the list of the signals held back (logged when the block ends): the
    caller drops them where the run is stopping anyway, and raises them once the file is
    complete where the run was finishing. Only the main thread can own signal handlers;
    elsewhere this does nothing (and yields an empty list).
    """
    held: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    previous = {s: signal.signal(s, lambda signum, frame: held.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield held
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if held:
            log.warning("%d interrupt(s) held back while reaching the safe state", len(held))


#: Reaching the safe state (drive ramped to zero, instruments closed, file state written)
#: takes about a second; past this many seconds every thread's stack goes to stderr.
SAFE_STATE_STALL_S = 10.0


@contextlib.contextmanager
def _stall_report(after_s: float = SAFE_STATE_STALL_S):
    """Print every thread's stack to stderr once if the block is still running ``after_s``
    seconds on, and go on waiting.

    Why: an aborted run once did not exit within 30 s in CI (the TUI's abort test, under the
    parallel suite's load) and left no trace of where it waited; this shows the operator, and
    the test's log, which call holds the safe state up. A watchdog thread of ours prints it
    (:mod:`daq.thread_stacks`): faulthandler's ``dump_traceback_later`` reads the frames
    without the GIL while the threads run and can crash the process (cpython#131580), here
    while the drive is being ramped down.
    """
    done = threading.Event()

    def watch() -> None:
        if not done.wait(after_s):
            write_to_stderr(f"the safe state is not reached after {after_s:g} s; every thread's stack:\n"
                            + thread_stacks(skip=threading.get_ident()))

    watchdog = threading.Thread(target=watch, name="safe-state stall report", daemon=True)
    try:
        watchdog.start()
    except RuntimeError:  # no thread to be had: reaching the safe state matters, the report not
        yield
        return
    try:
        yield
    finally:
        done.set()
        watchdog.join(1.0)


def _raw_rows_expected(setup: TestSetup, n_lines: int) -> int:
    """Raw sample rows a stepped-sine run keeps at most: every shaker's sub-line at every
    line dwelling its longest (``max_dwell_s``); 0 for other runs."""
    if setup.sine is None:
        return 0
    return n_lines * len(setup.shakers) * math.ceil(setup.sine.max_dwell_s * setup.daq.sample_rate_hz)


def _create_runfile(setup: TestSetup, path: Path) -> RunFile:
    if setup.excitation == "stepped_sine":
        from .stepped_sine import sine_grid

        freq = sine_grid(setup)
    else:
        from .random_run import random_bins

        freq = random_bins(setup)
    attrs = {"test_name": setup.name, "setup_sha256": setup.sha256, "software": f"ssidlab {_version()}",
             "excitation": setup.excitation,
             "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **coupling_attrs(setup)}
    meta = {"software_version": _version(), "python": platform.python_version(), "host": platform.node(),
            "started_utc": attrs["started_utc"],
            "channels": [c.__dict__ for c in setup.channels], "shakers": [s.__dict__ for s in setup.shakers]}
    return RunFile.create(path, kind=setup.excitation, setup_text=setup.text, setup_sha256=setup.sha256,
                          freq_hz=freq, outputs=setup.outputs, inputs=setup.inputs, reactions=setup.reactions,
                          channel_names=[c.name for c in setup.channels], meta=meta, attrs=attrs,
                          raw_time=setup.raw_time and setup.excitation == "stepped_sine",
                          raw_rows_expected=_raw_rows_expected(setup, len(freq)))


def _ctrl_c_latched(fn: Callable) -> Callable:
    """Run ``fn`` with :func:`daq.control.latching_interrupt_handler` for SIGINT in place of
    Python's default, so that a Ctrl-C raised where Python drops exceptions (a finalizer)
    still stops the run; a handler the caller installed (``ssidlab acquire``'s) stays."""

    @functools.wraps(fn)
    def wrapper(*args, **kw):
        if (threading.current_thread() is not threading.main_thread()
                or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
            return fn(*args, **kw)
        previous = signal.signal(signal.SIGINT, latching_interrupt_handler(KeyboardInterrupt))
        try:
            return fn(*args, **kw)
        finally:
            signal.signal(signal.SIGINT, previous)
            clear_interrupts()  # the run is over: a late Ctrl-C must not stop the next one

    return wrapper


@_ctrl_c_latched
def run_test(setup: TestSetup, *, out: str | None = None, resume: bool = False, sim: bool = False,
             echo: Callable[[str], None] = print, rig_factory: Callable[[TestSetup], Rig] | None = None,
             control: RunControl | None = None, events: Callable[[dict], None] | None = None,
             new_instruments: bool = False) -> dict:
    """Run (or resume) the test of ``setup``; returns a summary dict.

    Parameters
    ----------
    setup : TestSetup
    out : str, optional
        Run file (default: the setup's ``[output] file``). With ``resume``, the file to continue.
    resume : bool
        Continue an unfinished run file. ``setup`` may differ from the run's only in
        :data:`daq.resume.RESUMABLE_KEYS`; the instruments must answer as in the run's last
        session (:func:`daq.resume.instruments_not_the_same`) unless ``new_instruments``.
    new_instruments : bool
        With ``resume``: an instrument was replaced; continue with it and record so.
    sim : bool
        Start the simulated lab (:mod:`daq.simlab`) and run against it.
    rig_factory : callable, optional
        Builds the rig from the (possibly re-addressed) setup; default :class:`InstrumentRig`.
    control : RunControl, optional
        Pause / resume requests, honoured between lines (:mod:`daq.control`).
    events : callable, optional
        Receives the run's events as JSON-able dicts: ``instruments`` (identities, once the
        instruments answer), ``sub_line`` / ``line`` (stepped sine), ``spectrum`` (random),
        ``paused``, ``resumed``.

    Raises
    ------
    RunStopped
        A fault stopped the run (instruments safe, file resumable).
    InputError
        Bad setup or run file.
    KeyboardInterrupt
        Ctrl-C / SIGTERM (instruments safe, file resumable).
    """
    path = Path(out or setup.output_file)
    uff = uff_export_path(setup, path, out)
    for other, what in ((path, "the run file"), (Path(setup.source), "the setup file")):
        # Written at the end, the export would replace the measurement (or its setup).
        if uff is not None and os.path.realpath(uff) == os.path.realpath(other):
            raise InputError(f"{uff}: the UFF export ([output] uff) would overwrite {what}; "
                             "give one of them another name")
    world = None
    if sim:
        from .simlab import build_world
    if sim and not resume:
        # Before the run file exists: a bad [sim] table must not leave a failed file that
        # blocks the corrected setup's run ("exists already") and its resume alike.
        world = build_world(setup)
    if resume:
        rf = RunFile.open(path)
        try:
            stored = setup_in_effect(rf)
            changes = setup_changes_on_resume(stored, setup, path)
            sessions = rf.meta.get("sessions") or [{}]
            if rf.state != "complete" and sessions[-1].get("simulated") and not sim:
                # Its setup's addresses are the simulated lab's placeholders: without --sim
                # the resume would fail to reach them and blame the addresses.
                raise InputError(f"{path}: the run was measured on the simulated lab; resume it with --sim")
            if sim and rf.state != "complete":  # a complete run measures nothing more
                world = build_world(setup)
        except BaseException:
            rf.close()
            raise
        if rf.state == "complete":
            rf.close()
            echo(f"{path}: the run is complete; nothing to resume")
            summary = {"state": "complete", "file": str(path), "resumed": False}
            uff = uff_export_path(setup, path, out)
            if uff is not None and not uff.exists():
                # A run stopped after its file was complete (a Ctrl-C at the very end)
                # had its export cut: write it now from the file.
                from ssid.io import read_frf

                _export_uff(read_frf(path), uff, summary, echo)
            return summary
        echo(f"{path}: resuming ({rf.n_done} records, state was {rf.state!r})")
        ranges = range_changes(changes)
        if ranges:
            echo("DAQ input ranges changed for this session: "
                 + ", ".join(f"{name!r} {a:g} -> {b:g} V" for name, (a, b) in ranges.items()))
        others = [str(c) for c in changes if c.key != "range_volt"]
        if others:
            echo("setup changed for this session: " + "; ".join(others))
        rf.set_state("running")
    else:
        stored, changes = setup, []
        if not path.parent.is_dir():
            raise InputError(f"{path}: directory {str(path.parent)!r} does not exist")
        rf = _create_runfile(setup, path)
    ev = RunEvents(events)
    handle = None
    rig = None
    state = "failed"
    summary: dict = {}
    frf = None
    try:
        inst_setup = setup
        if sim:
            from .simlab import start_sim_lab

            handle, inst_setup = start_sim_lab(setup, world)
            echo("simulated lab started (generators, amplifiers, CAN FD DAQ on their real transports)")
        rig = (rig_factory or InstrumentRig)(inst_setup)
        meta = rf.meta
        replaced = []
        if resume and meta.get("sessions"):
            replaced = instruments_not_the_same(meta["sessions"][-1].get("instruments", {}), rig.identities())
            if replaced and not new_instruments:
                # Nothing has been driven yet: a swapped port would drive one shaker with
                # another's signal, and a simulated lab's lines are not the hardware's.
                raise RunStopped(f"{NOT_THE_SAME_INSTRUMENTS}: " + "; ".join(replaced)
                                 + ". Check the setup's addresses; if an instrument was replaced, "
                                 "resume with --new-instruments")
            if replaced:
                echo("instruments replaced since the last session: " + "; ".join(replaced))
        meta.setdefault("sessions", []).append({
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "instruments": rig.identities(),
            "simulated": bool(sim), "resumed_at_record": rf.n_done})
        if replaced:
            meta["sessions"][-1]["instruments_replaced"] = replaced
        if setup.sha256 != stored.sha256:
            # The setup this session runs with, for the next resume and for the record: which
            # lines were measured with which ranges, through which instruments' addresses.
            meta["sessions"][-1].update(
                setup_toml=setup.text, setup_sha256=setup.sha256,
                range_volt_changed={k: list(v) for k, v in range_changes(changes).items()},
                setup_changed=[{"table": c.table, "item": c.item, "key": c.key, "old": c.old, "new": c.new}
                               for c in changes])
        rf.set_meta(meta)
        ev.emit("instruments", identities=rig.identities(), simulated=bool(sim))
        rig.prepare()
        if setup.excitation == "stepped_sine":
            from .stepped_sine import SteppedSineRun

            runner = SteppedSineRun(setup, rig, rf, echo, control, ev)
        else:
            from .random_run import RandomRun

            runner = RandomRun(setup, rig, rf, echo, control, ev)
        summary = runner.run()
        frf = runner.frf()
        frf.attrs = {k: v for k, v in rf.f.attrs.items() if k not in ("format", "format_version", "quantity", "n_avg")}
        # The FRFs were formed with this session's setup (a run file from before the
        # correction was recorded gets it here).
        frf.attrs.update(coupling_attrs(setup))
        state = "complete"
    except InstrumentError as exc:
        state = f"stopped: {describe_fault(exc)}"
        raise RunStopped(f"run stopped safely: {describe_fault(exc)}", exc) from None
    except RunStopped as exc:
        state = f"stopped: {exc}"
        raise
    except KeyboardInterrupt:
        state = "interrupted"
        clear_interrupts()
        raise
    except BrokenPipeError:
        # The printout's reader went away (`| head`, a dead logger): stopped as a Unix tool
        # is by SIGPIPE, the file resumable as after Ctrl-C.
        state = "stopped: the output's reader went away (broken pipe)"
        raise
    except BaseException as exc:
        state = f"failed: {type(exc).__name__}: {exc}"
        raise
    finally:
        with _interrupts_deferred() as held, _stall_report():
            problems: list[str] = []
            if rig is not None:
                problems = rig.safe_state()
                try:
                    rig.close()
                except Exception as exc:  # closing must not hide the first error
                    problems.append(str(exc))
            if handle is not None:
                handle.stop()
            ended = state
            if state == "complete" and not problems:
                rf.finalize(frf)
            else:
                if problems:
                    state = f"{state}; {SAFE_STATE_NOT_CONFIRMED}: {'; '.join(problems)}"
                rf.set_state(state[:STATE_MAX_CHARS])
                rf.close()
            if problems:
                # Whatever ended the run (a fault, Ctrl-C, an error), an unconfirmed safe state
                # is what the engineer must hear first: never "stopped safely" or "interrupted".
                raise RunStopped(f"safe state NOT confirmed (check the instruments): {'; '.join(problems)}; "
                                 f"the run ended as: {ended}")
        if held and state == "complete":
            # A Ctrl-C while the finished run reached its safe state: the file is complete
            # now, and what follows (the UFF export) is cut as the operator asked; the
            # command says so, and a resume of the complete file does those steps.
            raise KeyboardInterrupt
    summary.update({"state": state, "file": str(path), "resumed": bool(resume)})
    uff = uff_export_path(setup, path, out)
    if uff is not None:
        _export_uff(frf, uff, summary, echo)
    summary["test_time_s"] = float(summary.get("test_time_s", np.nan))
    summary.update(_reciprocity(frf, echo))
    return summary


def uff_export_path(setup: TestSetup, path: Path, out: str | None) -> Path | None:
    """Where the UFF export of a run into ``path`` goes (None: the setup asks for none);
    ``out`` is the run file named on the command line, if one was."""
    if not setup.uff_file:
        return None
    uff = Path(setup.uff_file)
    if not uff.is_absolute() and out is not None:
        # Named after the run file: runs of one setup into different files (run1.h5,
        # run2.h5) must not overwrite each other's export.
        uff = path.with_suffix(uff.suffix or ".uff")
    return uff


def _export_uff(frf, uff: Path, summary: dict, echo) -> None:
    """The FRFs to ``uff`` (UFF 58), said and noted in ``summary``."""
    from ssid.exchange import write_uff_frf

    try:
        write_uff_frf(str(uff), frf)
    except InputError as exc:
        # The measurement is safe in the HDF5 file; a label UFF cannot carry must not
        # turn a finished run into a failure.
        summary["uff_error"] = str(exc)
        # Not through echo: that is the progress printout on stdout, which --quiet drops,
        # and a warning goes to stderr whatever the printout (docs/formats.md).
        print(f"warning: UFF export skipped: {exc}", file=sys.stderr, flush=True)
    else:
        summary["uff"] = str(uff)
        echo(f"exported {frf.n_out * frf.n_in} FRFs to {uff} (UFF 58)")


def _reciprocity(frf, echo) -> dict:
    """The run's reciprocity check (``ssid.reciprocity``) between its driven DOFs, said and
    summarised: a MIMO test's own check of its transducers' calibration and linearity."""
    from ssid.reciprocity import reciprocity_check

    rows = []
    for p in reciprocity_check(frf):
        echo(p.describe())
        row = {"dofs": [p.dof_a, p.dof_b], **p.curves.to_json_dict()}
        del row["agree"]  # the pair's verdict: its curves agree, or both are noise only
        row.update(reciprocal=p.reciprocal, noise_only=p.noise_only)
        rows.append(row)
    return {"reciprocity": rows, "n_not_reciprocal": sum(not r["reciprocal"] for r in rows)}
