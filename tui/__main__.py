"""``python -m tui [SETUP.toml] [--out RUN.h5] [--no-sim]``: the TUI without ``ssidlab tui``."""

import argparse
import sys

from tui.cli import add_tui_subcommand


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tui")
    sub = parser.add_subparsers(dest="command")
    add_tui_subcommand(sub)
    args = parser.parse_args(["tui", *(sys.argv[1:] if argv is None else argv)])
    return args.run(args)


if __name__ == "__main__":
    raise SystemExit(main())
