"""``python -m ssidlab`` and the ``ssidlab`` console command."""

import sys


def entry() -> int:
    """:func:`ssidlab.cli.main`, with a Ctrl-C while it is imported (numpy, scipy and h5py
    take most of the first second) an interrupt like any other: one line and status 130,
    not a traceback from inside an import."""
    try:
        from ssidlab.cli import main
    except KeyboardInterrupt:
        print("ssidlab: interrupted", file=sys.stderr)
        return 130
    return main()


if __name__ == "__main__":
    raise SystemExit(entry())
