"""``ssidlab export-model MODEL OUT``: a model's M, C, K to MATLAB, Nastran OP4 or DMIG.

``MODEL`` is anything :func:`ssid.matrix_io.read_analysis_model` reads (an ssidlab model
``.h5``, a ``.mat`` or an ``.op4``); the format of ``OUT`` comes from its extension (``.mat``,
``.op4``, ``.dmig`` / ``.bdf`` / ``.dat`` / ``.blk`` / ``.pch``) or ``--format``. Bad input
raises :class:`ssid.errors.InputError` (one line, exit status 2 through ``ssidlab.cli.main``).
See ``docs/exchange.md``.
"""

from __future__ import annotations

import argparse
from typing import Any

from ssid.errors import InputError
from ssidlab.argtypes import check_output_paths

__all__ = ["add_export_model_subcommand", "run_export_model"]

HELP = "Export a model's M, C, K to MATLAB (.mat), Nastran OP4 (.op4) or Nastran DMIG (.dmig/.bdf)."
FORMATS = ("mat", "op4", "dmig")


def add_export_model_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``export-model`` subparser to ``sub`` (an argparse subparsers action)."""
    p = sub.add_parser("export-model", prog="ssidlab export-model", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument("model", metavar="MODEL", help="model file (.h5 ssidlab-model, .mat, .op4)")
    p.add_argument("output", metavar="OUT", help="target file (.mat, .op4, .dmig, .bdf)")
    p.add_argument("--format", choices=FORMATS, help="output format (default: from OUT's extension)")
    p.add_argument("--ascii", action="store_true", help="OP4: ASCII instead of binary")
    p.add_argument("--names", type=_names, metavar="MASS,DAMPING,STIFFNESS",
                   help="OP4/DMIG matrix names (default MAA,BAA,KAA for OP4, "
                   "MSSID,BSSID,KSSID for DMIG)")
    p.add_argument("--quiet", action="store_true", help="do not print the summary line")
    p.set_defaults(run=run_export_model)
    return p


def _names(text: str) -> list[str]:
    names = [s.strip().upper() for s in text.split(",")]
    if len(names) != 3 or not all(names):
        raise argparse.ArgumentTypeError(f"expected three names MASS,DAMPING,STIFFNESS, got {text!r}")
    return names


def run_export_model(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab export-model``; returns 0, raises InputError on bad input."""
    from ssid.export import export_model, format_from_path

    fmt = args.format or format_from_path(args.output)
    if args.ascii and fmt != "op4":
        raise InputError("--ascii applies to OP4 output only")
    if args.names and fmt == "mat":
        raise InputError("--names applies to OP4 and DMIG output only (MAT uses M, C, K)")
    check_output_paths([args.model], [args.output])

    from ssid.matrix_io import read_analysis_model

    model = read_analysis_model(args.model)
    export_model(args.output, model, fmt, names=args.names, binary=not args.ascii)
    if not args.quiet:
        damped = "M, C, K" if model.C is not None else "M, K (undamped)"
        print(f"wrote {args.output}: {damped} over {model.n} DOFs as {fmt.upper()}")
    return 0
