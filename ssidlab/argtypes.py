"""argparse value types shared by the ``ssidlab`` subcommands."""

from __future__ import annotations

import argparse
import math

__all__ = ["frequency_hz"]


def frequency_hz(text: str) -> float:
    """argparse type for a frequency in Hz: finite and >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite frequency >= 0 Hz, got {text!r}")
    return value
