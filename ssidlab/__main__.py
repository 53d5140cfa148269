"""``python -m ssidlab`` and the ``ssidlab`` console command."""

import signal
import sys


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def entry() -> int:
    """:func:`ssidlab.cli.main`, with a Ctrl-C or a SIGTERM while it is imported (numpy,
    scipy and h5py take most of the first second) an interrupt like any other: one line and
    status 130, not a traceback from inside an import, nor a silent end with 143."""
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _interrupt)  # main() keeps it, as its own
    try:
        from ssidlab.cli import main
    except KeyboardInterrupt:
        print("ssidlab: interrupted", file=sys.stderr)
        return 130
    return main()


if __name__ == "__main__":
    raise SystemExit(entry())
