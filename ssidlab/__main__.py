"""``python -m ssidlab``: the same as the ``ssidlab`` console command."""

from ssidlab.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
