"""``ssidlab check``: is every instrument of a setup there, who is it, and is it ready?

    ssidlab check SETUP.toml|RUN.h5 [--sim] [--reset-faults] [--timeout-s S] [--json CHECK.json]

The check an engineer makes before a run (``daq.check``), without the TUI: each generator,
amplifier and the DAQ is opened on its own, identified and released in the safe state;
nothing is driven. One line per instrument, then a verdict. Given an unfinished run file,
it checks the instruments of the setup the run would resume with. ``--sim`` checks the
simulated lab, started on loopback for the check and stopped after it. ``--reset-faults``
first resets each amplifier's latched fault (after an interlock trip, say, once the door is
closed): the amplifier refuses while the cause is present, and nothing is switched on.

Exit status: 0 every instrument answered and is ready for the run; 3 one did not answer, or
answered in a state the run could not start from (an amplifier's interlock open or a fault
latched, a DAQ with fewer inputs than the setup uses); 2 bad input (one line
``ssidlab check: error: ...``).
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
from typing import Any

__all__ = ["add_check_subcommand"]

HELP = "Check the instruments of a setup: connect, identify, release (nothing is driven)."
EXIT_NOT_READY = 3  # as `ssidlab acquire` exits when an instrument stops a run


def add_check_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``check`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("check", prog="ssidlab check", help=HELP, description=HELP, allow_abbrev=False)
    p.add_argument("setup", metavar="SETUP.toml|RUN.h5",
                   help="test setup (TOML, see docs/acquisition.md), or an unfinished run file: the setup it "
                        "resumes with")
    p.add_argument("--sim", action="store_true", help="check the simulated lab (started for the check)")
    p.add_argument("--reset-faults", action="store_true",
                   help="first reset each amplifier's latched fault (refused by the amplifier while its cause is "
                        "present; nothing is switched on)")
    p.add_argument("--timeout-s", type=_positive_s, default=1.0, metavar="S",
                   help="how long each instrument may take to answer (default 1 s)")
    p.add_argument("--json", metavar="CHECK.json", help="write every instrument's state and the verdict as JSON")
    p.set_defaults(run=run_check)
    return p


def _positive_s(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value <= 60:
        raise argparse.ArgumentTypeError(f"must be in (0, 60] s, got {text}")
    return value


def _load(path: str):
    """The setup in ``path``: a setup file, or the one an unfinished run file resumes with."""
    import h5py

    from daq.resume import load_resume_setup
    from daq.setup import load_setup

    return load_resume_setup(path) if h5py.is_hdf5(path) else load_setup(path)


def run_check(args: argparse.Namespace) -> int:
    from daq.check import check_lab, check_verdict
    from ssidlab.argtypes import check_output_paths, write_json

    check_output_paths([args.setup], [args.json])
    setup = _load(args.setup)
    states = check_lab(setup, sim=args.sim, timeout_s=args.timeout_s, reset_faults=args.reset_faults)
    verdict = check_verdict(states) + (" (simulated lab)" if args.sim else "")
    rows = [(s.name, s.kind, s.address, s.identity or "-", s.state) for s in states]
    widths = [max(len(r[k]) for r in rows) for k in range(4)]
    for r in rows:
        print("  ".join(f"{v:<{w}}" for v, w in zip(r[:4], widths)) + "  " + r[4])
    print(verdict)
    if not args.reset_faults and any(s.ok and s.kind == "amplifier" and "fault latched" in s.not_ready
                                     for s in states):
        print(f"once a fault's cause is gone, reset it with: ssidlab check {shlex.quote(args.setup)} --reset-faults"
              + (" --sim" if args.sim else ""))
    if args.json:
        write_json(args.json, {"setup": args.setup, "simulated": bool(args.sim), "verdict": verdict,
                               "ready": all(s.ready for s in states),
                               "instruments": [dict(dataclasses.asdict(s), ready=s.ready) for s in states]})
    return 0 if all(s.ready for s in states) else EXIT_NOT_READY
