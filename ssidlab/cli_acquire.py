"""``ssidlab acquire``: run a vibration test described by a setup file.

    ssidlab acquire SETUP.toml [--sim] [--out RUN.h5] [--quiet]
    ssidlab acquire --resume RUN.h5 [SETUP.toml] [--sim] [--new-instruments] [--quiet]
    ... [--events] [--control-stdin]     (for a controlling program such as ``ssidlab tui``)

``--sim`` starts the simulated lab (``daq.simlab``) and runs against it through the real
drivers. ``--resume`` continues an interrupted run from its first incomplete line; a setup
file given may differ from the run's only in the channels' ``range_volt`` (a range too small
for the level stops a run), the instruments' addresses, the operator and the output file
names (``daq.resume``); without a file, the setup the run last ran with is used. The
instruments must answer as in the run's last session (generators' ``*IDN?``, the
amplifiers' and the DAQ's serials), or the resume stops before driving: ``--new-instruments``
continues with a replaced one.

``--events`` adds one line per run event to stdout, ``@event {json}`` (``daq.control``:
instrument identities, each sub-line's level, distortion, limit use and amplifier state,
each FRF line's |H| and coherence, pause and resume). ``--control-stdin`` takes commands
from stdin, one per line: ``pause`` (after the current line: outputs off, amplifiers
disabled), ``resume``, ``abort`` (as Ctrl-C). End of input also aborts: if the controlling
program dies, however it dies, the run stops safely instead of driving on unattended.

Exit status: 0 the run is complete; 2 bad input (setup file, run file, options; one line
``ssidlab acquire: error: ...``); 3 the run was stopped safely by a fault (a line
``ssidlab acquire: stopped: <why>``); 130 interrupted (Ctrl-C or SIGTERM); 141 stopped
because the reader of stdout went away (``| head``, a logger that died). After 3, 130 or 141
the run file is resumable, and a second line names it with the command that continues it
(after a DAQ overload, an instrument not reached, an amplifier trip or other instruments
answering, a third says what to change: ``daq.safety.resume_remedy``).
In every case all generator outputs are off and all amplifiers disabled when the command
ends.
"""

from __future__ import annotations

import argparse
import errno
import os
import shlex
import signal
import sys
import threading
from pathlib import Path
from typing import Any, NoReturn

from daq.thread_stacks import thread_stacks, write_to_stderr
from ssid.errors import InputError
from ssidlab.output_pump import OutputPump

__all__ = ["EXIT_INTERRUPTED", "EXIT_STOPPED", "add_acquire_subcommand", "run_acquire"]

HELP = "Run a stepped-sine or random vibration test from a setup file (real or simulated lab)."
EXIT_STOPPED = 3
#: The run went to its end and every FRF value is blanked (the setup's limits or sensors):
#: the bad-input status, as the setup is what to change.
EXIT_NOTHING_MEASURED = 2
EXIT_INTERRUPTED = 130


def add_acquire_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``acquire`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("acquire", prog="ssidlab acquire", help=HELP, description=HELP, allow_abbrev=False)
    p.add_argument("setup", nargs="?", metavar="SETUP.toml",
                   help="test setup (TOML, see docs/acquisition.md); optional with --resume")
    p.add_argument("--sim", action="store_true", help="start the simulated lab and run against it")
    p.add_argument("--out", metavar="RUN.h5", help="run file (default: the setup's [output] file)")
    p.add_argument("--resume", metavar="RUN.h5", help="continue this unfinished run file")
    p.add_argument("--new-instruments", action="store_true",
                   help="with --resume: an instrument answers as another than in the run's last session "
                        "because it was replaced; continue with it (recorded in the run file)")
    p.add_argument("--json", metavar="SUMMARY.json",
                   help="write the run summary as JSON; after a stop, the run file's state, its records, "
                        "the remedy (daq.safety.resume_remedy) and the command that continues it")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--events", action="store_true", help="also print run events as '@event {json}' lines")
    p.add_argument("--control-stdin", action="store_true",
                   help="read pause/resume/abort from stdin; end of input aborts safely")
    p.set_defaults(run=run_acquire)
    return p


def _print_thread_stacks(signum: int, frame: Any) -> None:
    """``kill -USR1``: every thread's stack to stderr, most recent call first.

    A Python-level signal handler: the main thread runs it holding the GIL, so no thread's
    frames change while they are read (``faulthandler.register``, used before, crashed a run:
    :mod:`daq.thread_stacks`). It interrupts the main thread anywhere, so it takes no lock the
    main thread may hold (a main thread starting a thread holds the thread registry's): the
    functions it calls take none.
    """
    # The main thread's own top frame is this handler; ``frame`` is where it was.
    write_to_stderr(thread_stacks(current=(threading.main_thread().ident, frame)))


def _print_event(event: dict) -> None:
    from daq.control import event_line

    print(event_line(event), flush=True)


def _read_control(control, stream) -> None:
    """Thread: stdin commands to ``control``; ``abort`` or end of input -> SIGINT to ourselves,
    which the run handles as Ctrl-C (safe state, resumable file)."""
    for line in stream:
        cmd = line.strip().lower()
        if cmd == "pause":
            control.request_pause()
        elif cmd == "resume":
            control.request_resume()
        elif cmd == "abort":
            break
        elif cmd:
            print(f"ssidlab acquire: ignored control command {cmd!r} (pause, resume, abort)", file=sys.stderr,
                  flush=True)
    # No resume first: the SIGINT interrupts the pause's wait itself, so a held run never
    # re-arms its amplifiers on the way out.
    os.kill(os.getpid(), signal.SIGINT)


def _say_how_to_continue(run_path: Path, sim: bool, setup_arg: str | None = None, resumed: bool = False) -> dict:
    """The line an engineer needs after a stop: where the measured lines are, and the
    command that continues the run from its first incomplete line. After a stop that a
    plain resume would meet again (:func:`daq.safety.resume_remedy`: a DAQ overload, an
    instrument not reached, an amplifier's latched fault, other instruments answering), also
    what to change and the command that continues with it.

    Returns the same for a controlling program (``--json``): the run file's ``state``,
    ``n_records``, ``remedy`` and ``continue_with``; empty without a run file."""
    from daq.safety import resume_remedy
    from daq.storage import peek_run_file

    if not run_path.is_file():
        return {}
    sim_flag = " --sim" if sim else ""
    run_q = shlex.quote(str(run_path))
    # A resume with a setup file that stopped before its session was recorded (an instrument
    # not reached, other instruments answering) would go back to the stored setup without it.
    again = f" {shlex.quote(setup_arg)}" if resumed and setup_arg else ""
    cmd = f"ssidlab acquire --resume {run_q}{again}{sim_flag}"
    # A fault before the first line (an instrument that never answered) leaves a file with
    # the setup only: say so rather than claim measured lines were kept.
    state, n = peek_run_file(run_path) or (None, 0)
    if state == "complete":
        # Interrupted after the file was finished: nothing to measure again, but the steps
        # after it (the UFF export) were cut, and a resume of a complete run does them.
        print(f"ssidlab acquire: the run file was complete ({n} measurement records in {run_path}); "
              f"the steps after it (a UFF export the setup asks for) are done by: {cmd}", file=sys.stderr,
              flush=True)
        return {"state": state, "file": str(run_path), "n_records": n, "remedy": None, "continue_with": cmd}
    kept = (f"{n} measurement records are kept in {run_path}" if n
            else f"nothing was measured yet; the setup is kept in {run_path}")
    setup = shlex.quote(setup_arg) if setup_arg else "SETUP.toml"
    remedy = resume_remedy(state, sim)
    if remedy == "new_run":
        # The drive of a random run is fixed (a resume may not change it): resumed, the next
        # average would drive as hard and stop at the same limit.
        print(f"ssidlab acquire: {kept}; a resume would drive as hard and exceed the limit again: lower "
              f"drive_vpp in [random] (or set limits the test allows) and start a new run: ssidlab acquire "
              f"{setup} --out NEW_RUN.h5{sim_flag}", file=sys.stderr, flush=True)
        return {"state": state, "file": str(run_path), "n_records": n, "remedy": remedy, "continue_with": None}
    print(f"ssidlab acquire: {kept}; continue with: {cmd}", file=sys.stderr, flush=True)
    with_setup = f"continue with it: ssidlab acquire --resume {run_q} {setup}{sim_flag}"
    if remedy == "range_volt":
        print(f"ssidlab acquire: if a DAQ input range is too small for the level, raise that channel's "
              f"range_volt in the setup and {with_setup}", file=sys.stderr, flush=True)
    elif remedy == "address":
        print(f"ssidlab acquire: if the instrument answers at another address now (a serial port "
              f"renumbered, a new IP address, a CAN adapter renamed), put that in the setup and {with_setup}",
              file=sys.stderr, flush=True)
    elif remedy == "reset_faults":
        check = shlex.quote(setup_arg) if resumed and setup_arg else run_q
        print(f"ssidlab acquire: once the cause is gone (door closed, E-stop released, amplifier cooled), "
              f"reset the amplifier's latched fault: ssidlab check {check} --reset-faults; then continue with: "
              f"{cmd}", file=sys.stderr, flush=True)
    elif remedy == "new_instruments":
        print(f"ssidlab acquire: if the setup's addresses are right and an instrument was replaced, "
              f"continue with: {cmd} --new-instruments", file=sys.stderr, flush=True)
    return {"state": state, "file": str(run_path), "n_records": n, "remedy": remedy, "continue_with": cmd}


class _Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: safe state, file kept resumable."""


def run_acquire(args: argparse.Namespace) -> int:
    from daq.control import RunControl, latching_interrupt_handler
    from daq.resume import load_resume_setup
    from daq.run import run_test
    from daq.safety import RunStopped
    from daq.setup import load_setup
    from drivers.amplifier import modbus_log_held_back
    from ssidlab.argtypes import check_output_paths

    if args.resume and args.out:
        raise InputError("--out and --resume exclude each other (the resumed file is written in place)")
    if args.new_instruments and not args.resume:
        raise InputError("--new-instruments goes with --resume (a new run has no instruments to compare)")
    if args.resume:
        setup = load_resume_setup(args.resume, args.setup)
        out = args.resume
    else:
        if not args.setup:
            raise InputError("a setup file is required (or --resume RUN.h5)")
        setup = load_setup(args.setup)
        out = args.out
    # The summary written over the run file would lose the measurement (the UFF export's
    # path is run_test's to check); a resume's run file is an input.
    check_output_paths([p for p in (args.setup, args.resume) if p],
                       [args.json, None if args.resume else str(Path(out or setup.output_file))])
    echo = (lambda m: None) if args.quiet else (lambda m: print(m, flush=True))
    previous = signal.signal(signal.SIGTERM, latching_interrupt_handler(_Terminated))
    # A process started in the background by a non-interactive shell (or by a CI runner)
    # inherits SIGINT as ignored, and Python then installs no KeyboardInterrupt handler: a
    # SIGINT (Ctrl-C, the TUI's abort) would be lost and the drive would keep running.
    # The latching handler also survives an interrupt raised where Python drops it.
    previous_int = signal.signal(signal.SIGINT, latching_interrupt_handler(KeyboardInterrupt))
    # `kill -USR1 PID` prints every thread's stack to stderr and the run goes on: where a run
    # that does not stop is waiting (the TUI's abort test asks so before it gives up).
    stacks_on_usr1 = hasattr(signal, "SIGUSR1")
    if stacks_on_usr1:
        previous_usr1 = signal.signal(signal.SIGUSR1, _print_thread_stacks)
    control = RunControl() if args.control_stdin else None
    run_path = Path(out or setup.output_file)
    # From here the run never waits for whoever reads its output (ssidlab.output_pump).
    pump = OutputPump().start()
    try:
        if control is not None:
            # Inside the try: input already at its end (``< /dev/null``) aborts at once, and
            # that abort is an interrupt like any other (safe state, how to continue, --json).
            threading.Thread(target=_read_control, args=(control, sys.stdin), name="acquire-control",
                             daemon=True).start()
        with modbus_log_held_back():
            summary = run_test(setup, out=out, resume=bool(args.resume), sim=args.sim, echo=echo, control=control,
                               events=_print_event if args.events else None, new_instruments=args.new_instruments)
    except RunStopped as exc:
        print(f"ssidlab acquire: stopped: {' '.join(str(exc).splitlines())}", file=sys.stderr)
        _write_summary(args.json, _say_how_to_continue(run_path, args.sim, args.setup, bool(args.resume)))
        return EXIT_STOPPED
    except KeyboardInterrupt:
        print("ssidlab acquire: interrupted (outputs off, amplifiers disabled)", file=sys.stderr)
        _write_summary(args.json, _say_how_to_continue(run_path, args.sim, args.setup, bool(args.resume)))
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        reader_gone = True
    else:
        reader_gone = False
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
        if stacks_on_usr1:
            signal.signal(signal.SIGUSR1, signal.SIG_DFL if previous_usr1 is None else previous_usr1)
        # The instruments are safe and the file closed: give the reader a few seconds for
        # the rest, but do not let one that stopped reading keep the process alive.
        pump.close()
    if reader_gone:
        _stopped_by_reader_gone(run_path, args)
    _write_summary(args.json, summary)
    if not args.quiet and "n_lines" in summary:
        print(f"done: {summary['file']} ({summary['state']}; {summary['n_lines']} lines, "
              f"{summary['test_time_s']:.1f} s test time{_caveats(summary)})")
    if summary.get("n_values") and summary.get("n_values_blanked") == summary["n_values"]:
        # A schedule run to its end is no measurement when nothing in it can be used: a
        # limit no drive keeps (every line aborted), or a sensor whose noise swamps the signal.
        n_aborted, n_sub = summary.get("n_aborted", 0), summary.get("n_sub_lines", 0)
        why = ("every sub-line aborted by a limit" if n_aborted and n_aborted == n_sub else
               f"{n_aborted} of {n_sub} sub-lines aborted by a limit, the others below min_coherence"
               if n_aborted else "coherence below min_coherence everywhere")
        print(f"ssidlab acquire: error: {summary['file']}: the run is complete but measured nothing usable: "
              f"every FRF value is blanked ({why}); check the setup's [limits], min_coherence and the "
              "sensors", file=sys.stderr)
        return EXIT_NOTHING_MEASURED
    return 0


def _stopped_by_reader_gone(run_path: Path, args: argparse.Namespace) -> NoReturn:
    """After the reader of stdout went away: said on stderr if that still works (stdout alone
    may have been piped), then the broken pipe goes on to ``ssidlab.cli.main``, which ends
    quietly with exit 141 as a tool killed by SIGPIPE would."""
    try:
        print("ssidlab acquire: stopped: the reader of the output went away (broken pipe); "
              "outputs off, amplifiers disabled", file=sys.stderr, flush=True)
        said = _say_how_to_continue(run_path, args.sim, args.setup, bool(args.resume))
    except OSError:  # stderr went with it
        said = {}
    _write_summary(args.json, said)
    raise BrokenPipeError(errno.EPIPE, "the reader of the output went away")


def _write_summary(path: str | None, summary: dict) -> None:
    """``--json``: the run's summary, or after a stop where the run stands and how it goes on."""
    from ssidlab.argtypes import write_json

    if path and summary:
        write_json(path, summary)


def _caveats(summary: dict) -> str:
    """What the engineer should know before using the FRFs, from the run's summary: the
    per-line and per-average messages have scrolled away by the end of a long run."""
    said = [f"; {n} {what.format('' if n == 1 else 's')}" for key, what in (
        ("n_aborted", "sub-line{} aborted"), ("n_held", "sub-line{} held below a limit"),
        ("n_level_off", "sub-line{} kept off the target level"),
        ("n_measured_again", "sub-line{} measured again below a limit"),
        ("unsettled_averages", "average{} not in steady state"), ("n_values_blanked", "FRF value{} blanked"),
        ("n_not_reciprocal", "pair{} of driven DOFs NOT reciprocal"))
        if (n := int(summary.get(key, 0)))]
    if peaks := summary.get("coarse_resolution_peaks_hz"):
        # The run's warning said why; the done line keeps it in view.
        said.append(f"; {len(peaks)} mode peak{'' if len(peaks) == 1 else 's'} narrower than ~3.5 lines")
    return "".join(said)
