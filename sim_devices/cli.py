"""``ssidlab sim-lab``: run the simulated lab as a standalone process.

The app (or a person) then points the drivers at it as at real hardware. Everything
listens on 127.0.0.1 only. On start, one JSON line on stdout gives the endpoints::

    {"generators": ["socket://127.0.0.1:40001"], "amplifiers": [{"host": ..., "port": ...}],
     "daq": {"can_channel": ..., "gateway": "127.0.0.1:40003", "inputs": [...]}}

The DAQ is reached through the CAN-over-TCP gateway (``CanFdDaq(interface="tcp",
channel="127.0.0.1:40003")``). The process runs until SIGINT/SIGTERM or ``--duration``.
Stopped by a signal, ``ssidlab sim-lab`` ends as every ``ssidlab`` command interrupted does
(status 130, ``ssidlab sim-lab: interrupted``); ``python -m sim_devices`` exits 0.

Wiring into ``ssidlab``: ``add_sim_lab_subcommand(subparsers)``; the parser gets
``run=run_sim_lab`` (``args.run(args)`` returns the exit status, or raises KeyboardInterrupt
once the lab is shut down after a signal).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

__all__ = ["add_sim_lab_subcommand", "build_parser", "main", "run_sim_lab"]


def _configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument("--generator-transport", choices=("tcp", "pty"), default="tcp",
                   help="SCPI generators on TCP sockets (socket://) or pseudo-terminals (default: tcp)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="simulated seconds per wall-clock second while acquiring; 0 = as fast as possible (default 1)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: until interrupted)")
    p.add_argument("--shakers", default="1+Z,8+Z", help="comma-separated shaker DOFs (default 1+Z,8+Z)")
    p.add_argument("--stand", action="store_true", help="put the structure on a flexible test stand with a load cell at 14+Z")
    p.add_argument("--no-noise", action="store_true", help="switch sensor noise off")
    p.add_argument("--seed", type=int, default=0, help="seed of every random stream (default 0)")
    p.add_argument("--gateway-port", type=int, default=0, help="TCP port of the CAN gateway (default: ephemeral)")
    p.set_defaults(run=run_sim_lab)
    return p


#: What ``--help`` says (the module docstring's first line is reStructuredText for the docs).
_DESCRIPTION = "Run the simulated lab (every simulated instrument on loopback) as a standalone process."


def add_sim_lab_subcommand(sub) -> argparse.ArgumentParser:
    """Add the ``sim-lab`` subcommand to an argparse subparsers object."""
    p = sub.add_parser("sim-lab", help="run the simulated instruments (loopback only) until interrupted",
                       description=_DESCRIPTION)
    return _configure(p)


def build_parser() -> argparse.ArgumentParser:
    return _configure(argparse.ArgumentParser(prog="python -m sim_devices", description=_DESCRIPTION))


def run_sim_lab(args: argparse.Namespace) -> int:
    """Start the lab, print its endpoints, wait; 0 after ``--duration``, 2 on bad options,
    KeyboardInterrupt (raised after the lab is shut down) when SIGINT/SIGTERM stopped it."""
    from .lab import SimLab, example_world
    from .world import WorldError

    prog = "ssidlab sim-lab"
    if args.speed < 0 or (args.duration is not None and args.duration < 0):
        print(f"{prog}: error: --speed and --duration must be >= 0", file=sys.stderr)
        return 2
    dofs = tuple(d.strip() for d in args.shakers.split(",") if d.strip())
    try:
        world = example_world(shaker_dofs=dofs, stand=args.stand, noise=not args.no_noise, seed=args.seed)
    except (WorldError, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    done = threading.Event()
    previous = {s: signal.signal(s, lambda *_: done.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with SimLab(world, generator_transport=args.generator_transport, speed=args.speed or None,
                    gateway=True, gateway_port=args.gateway_port) as lab:
            print(json.dumps(lab.endpoints()), flush=True)
            signalled = done.wait(args.duration)
    except OSError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    if signalled:
        # Only now, with the instruments closed: ssidlab's main turns it into the interrupt
        # every command reports (docs/formats.md: 130 and "ssidlab sim-lab: interrupted").
        raise KeyboardInterrupt
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except KeyboardInterrupt:
        # Scripts and tests run this module as a server they stop with a signal; for them
        # that is the normal end (docs/drivers.md).
        return 0
