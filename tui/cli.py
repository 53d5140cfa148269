"""``ssidlab tui``: the subcommand that starts the lab-run TUI (:mod:`tui.app`).

    ssidlab tui [SETUP.toml] [--out RUN.h5] [--model MODEL] [--no-sim]

``ssidlab/cli.py`` registers it by calling :func:`add_tui_subcommand` on its subparsers.
"""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_tui_subcommand", "run_tui"]

HELP = ("Terminal UI for a lab run: setup and instrument check, run with live FRF, pause/resume/abort, "
        "identified modes, MAC, discrepancy, exports.")


def add_tui_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``tui`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("tui", prog="ssidlab tui", help=HELP, description=HELP, allow_abbrev=False)
    p.add_argument("setup", nargs="?", metavar="SETUP.toml", help="setup file to load at start")
    p.add_argument("--out", metavar="RUN.h5", help="run file (default: the setup's [output] file)")
    p.add_argument("--model", metavar="MODEL", help="analysis model file for MAC and the discrepancy workflow "
                   "(model .h5, .mat, .op4; default with the simulated lab: its nominal model)")
    p.add_argument("--no-sim", dest="sim", action="store_false",
                   help="start with the 'simulated lab' switch off (real instruments)")
    p.set_defaults(run=run_tui)
    return p


def run_tui(args: argparse.Namespace) -> int:
    from tui.app import main

    return main(args.setup, out=args.out, sim=args.sim, model=args.model)
