"""argparse value types and output-path checks shared by the ``ssidlab`` subcommands."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from ssid.errors import InputError

__all__ = ["frequency_hz", "check_output_paths"]


def frequency_hz(text: str) -> float:
    """argparse type for a frequency in Hz: finite and >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite frequency >= 0 Hz, got {text!r}")
    return value


def check_output_paths(inputs: list[str], outputs: list[str | None]) -> None:
    """Refuse output paths that cannot be written, collide, or would overwrite an input.

    Checked before any work, so that a typo does not cost a long computation.
    """
    sources = {os.path.realpath(s) for s in inputs}
    seen: set[str] = set()
    for path in outputs:
        if path is None:
            continue
        real = os.path.realpath(path)
        if real in sources:
            which = "the input file" if len(sources) == 1 else "an input file"
            raise InputError(f"{path}: output would overwrite {which}")
        if real in seen:
            raise InputError(f"{path}: given for two different outputs")
        seen.add(real)
        if os.path.isdir(path):
            raise InputError(f"{path}: is a directory, expected a file name")
        parent = Path(path).parent
        if not parent.is_dir():
            raise InputError(f"{path}: cannot write, directory {str(parent)!r} does not exist")
