"""The ``ssidlab`` command line.

Exit status and error rules (also in ``docs/formats.md``):

* 0 -- success.
* 2 -- bad input: an unreadable or malformed file, NaN/Inf data, shapes or labels that do not
  agree, an unknown or missing option, an output path that cannot be written, or an
  identification that cannot be carried out on the data given. One line on stderr:
  ``ssidlab <subcommand>: error: <message>``.
* 1 -- an internal error (a bug): one line ``ssidlab <subcommand>: internal error: <type>:
  <message>``. With the environment variable ``SSIDLAB_DEBUG=1`` the exception is re-raised
  so that the traceback can be seen.

Never a traceback otherwise: scripts and acceptance checks read stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ssid.errors import IdentificationError, InputError
from ssid.io import write_model
from ssidlab import __version__
from ssidlab.argtypes import check_output_paths, say

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a tool killed by it

DEBUG_ENV = "SSIDLAB_DEBUG"


# ----------------------------------------------------------------------------------------------
# Entry point
# ----------------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``ssidlab`` command line and return its exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 on success, 2 on bad input, 1 on an internal error, 130 interrupted.
    """
    with _interruptible(), _terminated_as_interrupted():
        return _run(argv)


def _run(argv: Sequence[str] | None) -> int:
    try:
        # Building the parser imports every subcommand (about a second): a Ctrl-C then is
        # an interrupt like any other, not a traceback from inside an import.
        parser, subcommands = _build_parser()
    except KeyboardInterrupt:
        say("ssidlab: interrupted")
        return EXIT_INTERRUPTED
    try:
        args, extras = parser.parse_known_args(argv)
        if args.command is None:
            # COMMAND is checked here, not by argparse (which would say only that it is
            # missing): "ssidlab --bogus" must name the option it does not know.
            parser.error(f"unrecognized arguments: {' '.join(extras)}" if extras
                         else "the following arguments are required: COMMAND")
        if extras:
            # Report stray options against the subcommand they were given to, so the message
            # reads "ssidlab identify: error: ..." rather than the bare program name.
            owner = subcommands.get(getattr(args, "command", None), parser)
            owner.error(f"unrecognized arguments: {' '.join(extras)}")
    except _UsageError as exc:
        say(f"{exc.prog}: error: {exc.message}")
        return EXIT_BAD_INPUT
    except SystemExit as exc:  # --help and --version print their text and exit 0
        return exc.code if isinstance(exc.code, int) else EXIT_OK

    prog = f"ssidlab {args.command}"
    if args.command == "tui" and threading.current_thread() is threading.main_thread():
        # Textual owns the terminal and its event loop; SIGTERM keeps its default there (the
        # runs it started see their control input end and stop safely).
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        # Library warnings (numpy, scipy) are held back: on success they are shown one line
        # each, on failure they are dropped, so an error is always exactly one line.
        with warnings.catch_warnings(record=True) as caught:
            status = args.run(args)
        for message in dict.fromkeys(str(w.message) for w in caught):
            say(f"warning: {message}")
        return status
    except (InputError, IdentificationError) as exc:
        say(f"{prog}: error: {exc}")
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # The reader of stdout went away (``ssidlab ... | head``): its files are written, only
        # the printout was cut. Quiet, as a Unix tool killed by SIGPIPE; stdout goes to
        # /dev/null so that the interpreter's final flush does not raise again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as exc:  # an output path that cannot be written
        say(f"{prog}: error: {exc}")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        say(f"{prog}: interrupted")
        return EXIT_INTERRUPTED
    except Exception as exc:
        if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
            raise
        say(f"{prog}: internal error: {type(exc).__name__}: {exc}")
        return EXIT_INTERNAL


# ----------------------------------------------------------------------------------------------
# Parser
# ----------------------------------------------------------------------------------------------


class _UsageError(Exception):
    """A command-line usage error, carried up to :func:`main` instead of exiting."""

    def __init__(self, prog: str, message: str) -> None:
        super().__init__(message)
        self.prog = prog
        self.message = message


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line (no usage block) and never exit by themselves."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(self.prog, message)

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        """As argparse's, but an option this parser does not know is named before a missing
        required one: ``ssidlab demo --bogus`` said "required: --out", which sends the user
        after the wrong mistake."""
        try:
            return super().parse_known_args(args, namespace)
        except _UsageError as exc:
            if exc.prog != self.prog or "arguments are required" not in exc.message:
                raise  # another parser's (a subcommand's, on its way up), or another error
            unknown = [a for a in (sys.argv[1:] if args is None else args)
                       if a.startswith("--") and a.split("=", 1)[0] not in self._option_string_actions]
            if not unknown:
                raise
            raise _UsageError(self.prog, f"unrecognized arguments: {' '.join(unknown)}") from None


def _build_parser() -> tuple[_Parser, dict[str, _Parser]]:
    """The top-level parser and the subcommand parsers by name."""
    parser = _Parser(
        prog="ssidlab",
        description="Vibration tests and frequency-domain substructure identification of M, C, K.",
        allow_abbrev=False,  # abbreviations would silently change meaning as options are added
    )
    parser.add_argument("--version", action="version", version=f"ssidlab {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")  # required: checked in _run
    for add in _SUBCOMMANDS:
        add(sub)
    return parser, dict(sub.choices)


def _add_subcommand(sub: Any, name: str, help_text: str) -> _Parser:
    return sub.add_parser(
        name, prog=f"ssidlab {name}", help=help_text, description=help_text, allow_abbrev=False
    )




# ----------------------------------------------------------------------------------------------
# ssidlab demo
# ----------------------------------------------------------------------------------------------


def _add_identify(sub: Any) -> None:
    from ssidlab.cli_identify import add_identify_subcommand

    add_identify_subcommand(sub)


# ----------------------------------------------------------------------------------------------
# ssidlab demo
# ----------------------------------------------------------------------------------------------


def _add_demo(sub: Any) -> None:
    p = _add_subcommand(sub, "demo", "The main job end to end on the embedded default (see README).")
    p.add_argument("--out", metavar="DIR", required=True, help="directory for all results")
    p.add_argument(
        "--example", action="store_true",
        help="instead of the simulated lab, identify the bundled synthetic example (seconds)",
    )
    p.set_defaults(run=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise InputError(f"{args.out}: exists and is not a directory")
    if args.example:
        from ssidlab.demo import run_demo

        run_demo(args.out)
    else:
        from ssidlab.lab_demo import run_lab_demo

        run_lab_demo(args.out)
    return EXIT_OK


def _add_bands(sub: Any) -> None:
    from ssidlab.cli_bands import add_bands_subcommand

    add_bands_subcommand(sub)


def _add_pseudo(sub: Any) -> None:
    from ssidlab.cli_pseudo import add_pseudo_subcommand

    add_pseudo_subcommand(sub)


def _add_place(sub: Any) -> None:
    from ssidlab.cli_place import add_place_subcommand

    add_place_subcommand(sub)


def _add_correlate(sub: Any) -> None:
    from ssidlab.cli_correlate import add_correlate_subcommand

    add_correlate_subcommand(sub)


def _add_sim_lab(sub: Any) -> None:
    from sim_devices.cli import add_sim_lab_subcommand

    add_sim_lab_subcommand(sub)


def _add_convert(sub: Any) -> None:
    from ssidlab.cli_convert import add_convert_subcommand

    add_convert_subcommand(sub)


def _add_export_model(sub: Any) -> None:
    from ssidlab.cli_export import add_export_model_subcommand

    add_export_model_subcommand(sub)


def _add_discrepancy(sub: Any) -> None:
    from ssidlab.cli_discrepancy import add_discrepancy_subcommand

    add_discrepancy_subcommand(sub)


def _add_acquire(sub: Any) -> None:
    from ssidlab.cli_acquire import add_acquire_subcommand

    add_acquire_subcommand(sub)


def _add_compare(sub: Any) -> None:
    from ssidlab.cli_compare import add_compare_subcommand

    add_compare_subcommand(sub)


def _add_check(sub: Any) -> None:
    from ssidlab.cli_check import add_check_subcommand

    add_check_subcommand(sub)


def _add_sim_model(sub: Any) -> None:
    p = _add_subcommand(
        sub, "sim-model",
        "Write the nominal model of a simulated-lab setup (no hidden effects) as a model file.",
    )
    p.add_argument("setup", metavar="SETUP.toml", help="test setup with a [sim] section")
    p.add_argument("--out", metavar="MODEL.h5", required=True, help="model file to write")
    p.add_argument(
        "--substructure", action="store_true",
        help="the structure alone (the FE model to correlate with), not as mounted on its stand",
    )
    p.set_defaults(run=_run_sim_model)


def _run_sim_model(args: argparse.Namespace) -> int:
    from daq.setup import load_setup
    from daq.simlab import nominal_model

    check_output_paths([args.setup], [args.out])
    model = nominal_model(load_setup(args.setup), mounted=not args.substructure)
    write_model(args.out, model)
    print(f"wrote {args.out}: {len(model.dofs)} DOFs")
    return EXIT_OK


def _add_tui(sub: Any) -> None:
    from tui.cli import add_tui_subcommand

    add_tui_subcommand(sub)


# Each subcommand is an _add_<name>(sub) that builds its parser with _add_subcommand() (or
# sub.add_parser) and sets `run=...`; list it here. Errors follow the same rules through main().
_SUBCOMMANDS = (
    _add_identify, _add_bands, _add_pseudo, _add_place, _add_demo, _add_correlate, _add_compare, _add_sim_lab,
    _add_convert, _add_export_model, _add_discrepancy, _add_check, _add_acquire, _add_tui, _add_sim_model,
)


# ----------------------------------------------------------------------------------------------
# Output helpers
# ----------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _interruptible() -> Iterator[None]:
    """SIGINT raises KeyboardInterrupt from the first line, also in a process started with
    SIGINT ignored (in the background by a non-interactive shell or a CI runner, or by a
    controlling program). ``ssidlab acquire`` takes SIGINT from such a start on purpose (its
    run handler, ``daq.control``); before that handler was in place, an interrupt in the
    command's first second was lost and the run went on to drive. Only an ignored SIGINT is
    changed, only in the main thread (the only one that may set one), and it is ignored
    again afterwards (for a program embedding ``main``)."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) != signal.SIG_IGN:
        yield
        return
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _terminated_as_interrupted() -> Iterator[None]:
    """SIGTERM (a job scheduler's or a controlling program's stop) raises KeyboardInterrupt,
    so that a command ends as after Ctrl-C: one line, status 130, and no output file half
    written (they are written whole or not at all), instead of dying silently with 143.
    ``acquire`` and ``sim-lab`` put their own handlers in place for their runs. Only where
    SIGTERM has its default action, only in the main thread, restored afterwards."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) != signal.SIG_DFL:
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
