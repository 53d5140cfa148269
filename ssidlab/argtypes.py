"""argparse value types, output-path checks and file helpers shared by the ``ssidlab``
subcommands."""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ssid.errors import InputError
from ssid.files import written_atomically
from ssid.jsonutil import to_jsonable

__all__ = ["check_output_paths", "fe_normal_modes", "frequency_hz", "label_list", "open_fraction",
           "parse_mode_list", "percentage", "positive_number", "say", "whole_number", "write_chart",
           "write_json"]


def frequency_hz(text: str) -> float:
    """argparse type for a frequency in Hz: finite and >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite frequency >= 0 Hz, got {text!r}")
    return value


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def open_fraction(text: str, what: str = "a number") -> float:
    """argparse type for a number strictly between 0 and 1 (an overlap, a damping ratio);
    ``what`` names it in the message."""
    value = _number(text)
    if not 0.0 < value < 1.0:  # also refuses NaN
        raise argparse.ArgumentTypeError(f"must be {what} between 0 and 1, got {text!r}")
    return value


def positive_number(text: str) -> float:
    """argparse type for a finite number > 0."""
    value = _number(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def percentage(text: str) -> float:
    """argparse type for a percentage: finite and >= 0."""
    value = _number(text)
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite percentage >= 0, got {text!r}")
    return value


def whole_number(text: str, minimum: int = 1) -> int:
    """argparse type for an integer >= ``minimum`` (a count: sensors, partitions)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {text!r}")
    return value


def parse_mode_list(text: str) -> list[int]:
    """argparse type: ``"1-10,17,18"`` -> ``[1, ..., 10, 17, 18]`` (1-based, distinct, sorted).

    A mode given twice (``"1,1,2"``, ``"1-3,2"``) is refused, as a repeated label is by
    :func:`label_list`: dropped silently, it left one target fewer than the user counted.
    """
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:\s*-\s*(\d+))?", part)
        if not m:
            raise argparse.ArgumentTypeError(f"not a mode list: {text!r} (e.g. '1-10,17,18')")
        lo = int(m.group(1))
        hi = int(m.group(2) or lo)
        if lo < 1:
            raise argparse.ArgumentTypeError(f"bad mode range {part!r}: modes count from 1")
        if hi < lo:
            raise argparse.ArgumentTypeError(f"bad mode range {part!r}: the range is reversed (write {hi}-{lo})")
        again = out.intersection(range(lo, hi + 1))
        if again:
            raise argparse.ArgumentTypeError(f"mode {min(again)} is repeated in {text!r}")
        out.update(range(lo, hi + 1))
    return sorted(out)


def label_list(text: str) -> list[str]:
    """argparse type: ``"4+Z,8+Z"`` -> ``["4+Z", "8+Z"]`` (distinct, non-empty labels)."""
    labels = [s.strip() for s in text.split(",")]
    if not all(labels):
        raise argparse.ArgumentTypeError(f"empty DOF label in {text!r}")
    if len(set(labels)) != len(labels):
        raise argparse.ArgumentTypeError(f"a DOF label is repeated in {text!r}")
    return labels




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
        # samefile also catches a hard link to an input, which realpath does not resolve
        if real in sources or (os.path.exists(path) and any(
                os.path.exists(s) and os.path.samefile(s, path) for s in inputs)):
            which = "the input file" if len(sources) == 1 else "an input file"
            raise InputError(f"{path}: output would overwrite {which}")
        if real in seen:
            raise InputError(f"{path}: given for two different outputs")
        seen.add(real)
        if os.path.isdir(path):
            raise InputError(f"{path}: is a directory, expected a file name")
        if os.path.exists(path) and not os.path.isfile(path):
            # Said at the write too (ssid.files.written_atomically), but after the work.
            raise InputError(f"{path}: cannot write (it exists and is not a regular file: a device, a pipe "
                             "or a socket; give the name of a file)")
        parent = Path(path).parent
        if not parent.is_dir():
            raise InputError(f"{path}: cannot write, directory {str(parent)!r} does not exist")
        try:  # a directory that takes no file (read-only, /proc): said now, not after the work
            with tempfile.NamedTemporaryFile(dir=parent, prefix=".ssidlab-probe-"):
                pass
        except OSError as exc:
            raise InputError(f"{path}: cannot write in directory {str(parent)!r} "
                             f"({exc.strerror or exc})") from None


def chart_file(text: str) -> str:
    """A chart's file name whose extension matplotlib can write (png, pdf, svg, ...): checked
    when the options are read, not after the computation the chart shows."""
    from matplotlib.figure import Figure

    kinds = Figure().canvas.get_supported_filetypes()
    ext = Path(text).suffix.lower().lstrip(".")
    if ext not in kinds:
        raise argparse.ArgumentTypeError(
            f"{text!r}: a chart is written as one of {', '.join(sorted(kinds))} (by its extension)")
    return text


def write_chart(path: str, draw: Callable[[str], Any], what: str = "the chart") -> Any:
    """Run ``draw(path)`` (a matplotlib writer); a file-system failure becomes one line.

    Returns what ``draw`` returns (e.g. the files written)."""
    try:
        return draw(path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write {what} ({exc.strerror or exc})") from None


def say(message: str) -> None:
    """Write one line to stderr, folding any embedded line breaks (a warning or an error)."""
    print(" ".join(str(message).splitlines()), file=sys.stderr)


def write_json(path: str | os.PathLike, data: dict) -> None:
    """Write ``data`` as strict, indented JSON (numpy types as Python ones, NaN as null),
    whole or not at all (:func:`ssid.files.written_atomically`): a full disk must not leave a
    truncated summary, nor replace a good one."""
    text = json.dumps(to_jsonable(data), indent=1) + "\n"
    with written_atomically(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def fe_normal_modes(path: str) -> tuple[Any, np.ndarray, np.ndarray]:
    """An analysis model file and its normal modes: ``(model, f_hz (m,), phi (n, m))``,
    mass-normalised, ascending. A model whose M is not positive definite (massless DOFs of a
    lumped model) is bad input, with what to do about it; so is one whose K has a clearly
    negative eigenvalue (an unstable model: its modes would be read as 0 Hz). Round-off on
    rigid-body modes (:func:`ssid.tam.n_unstable_modes`) counts as 0 Hz. A model whose K
    is zero is bad input too (:func:`ssid.tam.require_elastic_modes`): the sensors placed for
    its modes, or the target modes picked from them, would be an arbitrary basis's."""
    from ssid.matrix_io import read_analysis_model
    from ssid.tam import normal_modes, require_elastic_modes, require_stable_stiffness

    model = read_analysis_model(path)
    try:
        lam, phi = normal_modes(model.M, model.K)
    except np.linalg.LinAlgError:
        raise InputError(f"{path}: M is not positive definite (massless DOFs?); reduce them "
                         "out first, e.g. by Guyan reduction") from None
    require_stable_stiffness(lam, path)
    require_elastic_modes(model.K, path, "what is computed from its modes")
    return model, np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi), phi
