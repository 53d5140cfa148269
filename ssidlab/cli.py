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
import json
import math
import os
import signal
import sys
import threading
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ssid.errors import IdentificationError, InputError
from ssid.io import read_measured_frf, write_model
from ssidlab import __version__
from ssidlab.argtypes import check_output_paths, frequency_hz

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a tool killed by it

DEBUG_ENV = "SSIDLAB_DEBUG"

SOLVERS = ("ml", "ls", "tls", "stls")
DAMPING_CHOICES = ("auto", "identified", "modal")  # ssid.identify.DAMPING_OPTIONS
# What each written C is, for the summary line (docs/formats.md, identify's damping_matrix).
_DAMPING_WORDS = {"identified": " (Eq. 3.15)", "modal": " (the roots' damping ratios on the real modes)",
                  "step1": " (step 1's M^-1 C on the written M)",
                  "output_error": " (M, C, K refined together to the data by output error)"}


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
        _say("ssidlab: interrupted")
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
        _say(f"{exc.prog}: error: {exc.message}")
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
            _say(f"warning: {message}")
        return status
    except (InputError, IdentificationError) as exc:
        _say(f"{prog}: error: {exc}")
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # The reader of stdout went away (``ssidlab ... | head``): its files are written, only
        # the printout was cut. Quiet, as a Unix tool killed by SIGPIPE; stdout goes to
        # /dev/null so that the interpreter's final flush does not raise again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as exc:  # an output path that cannot be written
        _say(f"{prog}: error: {exc}")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        _say(f"{prog}: interrupted")
        return EXIT_INTERRUPTED
    except Exception as exc:
        if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
            raise
        _say(f"{prog}: internal error: {type(exc).__name__}: {exc}")
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
# ssidlab identify
# ----------------------------------------------------------------------------------------------


def _add_identify(sub: Any) -> None:
    p = _add_subcommand(sub, "identify", "Identify M, C, K from a measured FRF file (SSID).")
    p.add_argument("frf", metavar="FRF.h5", help="measured FRFs (ssidlab-frf file)")
    p.add_argument(
        "--out", metavar="MODEL.h5", required=True,
        help="identified model (ssidlab-model file) over the FRF file's output DOFs",
    )
    p.add_argument(
        "--json", metavar="RESULT.json", required=True,
        help="natural frequencies, damping ratios and fit details",
    )
    p.add_argument(
        "--solver", choices=SOLVERS, default=None,
        help="ml: maximum likelihood, weights each line by its noise (default); "
        "ls: least squares; tls: total least squares; stls: scaled total least squares",
    )
    p.add_argument("--fmin", type=frequency_hz, metavar="HZ", help="lowest frequency line used")
    p.add_argument("--fmax", type=frequency_hz, metavar="HZ", help="highest frequency line used")
    p.add_argument(
        "--damping", choices=DAMPING_CHOICES, default="auto",
        help="identified: C from the identified state-space matrices; modal: C rebuilt from "
        "the identified damping ratios on the real modes; auto (default): the one whose model "
        "reproduces the measured FRFs better",
    )
    p.add_argument(
        "--select-band", action="store_true",
        help="reduced-order model (more modes in the band than sensors): choose the band and "
        "solver from the data, the band-processed modal model when it is physical "
        "(docs/algorithm.md); the solver is then chosen too",
    )
    p.add_argument("--quiet", action="store_true", help="do not print the mode table")
    p.set_defaults(run=_run_identify)


def _run_identify(args: argparse.Namespace) -> int:
    # Cheap checks first, so a typo does not cost an identification run.
    if args.select_band and args.solver is not None:
        raise InputError("--select-band chooses the solver from the data; leave out --solver")
    if args.fmin is not None and args.fmax is not None and args.fmin >= args.fmax:
        raise InputError(f"--fmin ({args.fmin:g} Hz) must be below --fmax ({args.fmax:g} Hz)")
    check_output_paths([args.frf], [args.out, args.json])
    frf = read_measured_frf(args.frf)
    _check_band(args.frf, frf, args.fmin, args.fmax)

    # Imported here: the solver stack is heavy, and input errors and --help must work even
    # when it cannot be imported.
    from ssid.identify import identify_mck

    if args.select_band:
        from ssid.band_select import identify_mck_band_select

        lo = float(frf.freq_hz[0]) if args.fmin is None else args.fmin
        hi = float(frf.freq_hz[-1]) if args.fmax is None else args.fmax
        result = identify_mck_band_select(frf.band(lo, hi), damping=args.damping)
    else:
        result = identify_mck(
            frf, solver=args.solver or "ml", f_min_hz=args.fmin, f_max_hz=args.fmax,
            damping=args.damping,
        )
    if list(result.dofs) != frf.outputs:
        raise RuntimeError(
            f"identified model DOFs {list(result.dofs)!r} differ from the FRF outputs "
            f"{frf.outputs!r}"
        )
    try:
        write_model(args.out, result.to_model())
    except InputError as exc:
        # Our own result failing validation is a bug, not bad input: report it as internal.
        raise RuntimeError(f"identified model failed validation: {exc}") from exc
    summary = result.to_json_dict()
    _write_json(args.json, summary)

    for message in result.warnings:
        _say(f"warning: {message}")
    if not args.quiet:
        choice = ((summary.get("info") or {}).get("band_select") or {}).get("choice")
        if choice and choice not in result.warnings:
            print(choice)
        print(_mode_table(summary))
        err = (summary.get("checks") or {}).get("frf_relative_rms_error")
        if err is not None:
            which = summary.get("damping_matrix")
            print(f"written model: damping matrix {which}{_DAMPING_WORDS.get(which, '')}; its FRFs differ "
                  f"from the data by {_fmt(err, 100.0, '.3g')} % (relative RMS over the band)")
    return EXIT_OK


def _check_band(source: str, frf, f_min: float | None, f_max: float | None) -> None:
    lo = -math.inf if f_min is None else f_min
    hi = math.inf if f_max is None else f_max
    in_band = (frf.freq_hz >= lo) & (frf.freq_hz <= hi)
    covers = f"the file covers {frf.freq_hz[0]:g} to {frf.freq_hz[-1]:g} Hz"
    if not in_band.any():
        raise InputError(f"{source}: no frequency lines between --fmin and --fmax ({covers})")
    if not frf.valid_mask()[in_band].any():
        raise InputError(f"{source}: every value in the selected band is marked invalid")


def _mode_table(summary: dict) -> str:
    """The roots (step 1) and, beside them, the undamped frequencies of the written M, K: the
    two agree for a full-order fit and may not for a reduced-order one (a free test), whose
    M, K are step 2's fit to those roots. Rigid-body modes (``R1``...) head the table."""
    freqs = summary.get("natural_freq_hz", [])
    zetas = summary.get("damping_ratio", [])
    undamped = summary.get("undamped_freq_hz", [])
    # A free-free model's rigid-body modes come first in eig(K, M) (at 0 Hz) and have no
    # root among the modes: they get their own rows, and the modes pair with the rest.
    n_rigid = int(summary.get("n_rigid_body_modes") or 0)
    lines = [f"{'mode':>4}  {'f_n [Hz]':>12}  {'damping [%]':>11}  {'M,K f [Hz]':>12}"]
    lines += [f"{f'R{k}':>4}  {'rigid body':>12}  {'-':>11}  {_fmt(0.0, 1.0, '.4f'):>12}"
              for k in range(1, n_rigid + 1)]
    for k, (f_n, zeta) in enumerate(zip(freqs, zetas), start=1):
        f_mk = undamped[n_rigid + k - 1] if n_rigid + k <= len(undamped) else None
        lines.append(f"{k:>4}  {_fmt(f_n, 1.0, '.4f'):>12}  {_fmt(zeta, 100.0, '.3f'):>11}  "
                     f"{_fmt(f_mk, 1.0, '.4f'):>12}")
    return "\n".join(lines)


def _fmt(value: Any, scale: float, spec: str) -> str:
    # Undetermined values arrive as None (JSON null) or NaN; show them as a dash.
    if value is None or not math.isfinite(float(value)):
        return "-"
    return format(scale * float(value), spec)


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
# sub.add_parser) and sets `run=...`; errors follow the same rules through main().
# Each gets an _add_<name>(sub) that builds its parser with _add_subcommand() and sets
# `run=_run_<name>`; list it here. Errors follow the same rules through main().
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


def _say(message: str) -> None:
    """Write one line to stderr, folding any embedded line breaks."""
    print(" ".join(str(message).splitlines()), file=sys.stderr)


def _write_json(path: str, data: dict) -> None:
    text = json.dumps(data, indent=2, default=_json_default)
    Path(path).write_text(text + "\n", encoding="utf-8")


def _json_default(value: Any) -> Any:
    # Results carry numpy arrays and scalars; JSON wants lists and Python numbers.
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
