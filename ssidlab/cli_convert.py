"""``ssidlab convert IN OUT``: UFF (universal file) <-> the ssidlab HDF5 and JSON files.

The direction comes from the files themselves: the input's content (HDF5 ``format``
attribute, JSON, or UFF ``-1`` delimiters) and the output's extension.

========================  =====================  ==============================================
IN                        OUT                    what
========================  =====================  ==============================================
FRF file (``.h5``)        ``.uff`` / ``.unv``    FRFs, coherence, reactions as datasets 58 (58b
                                                 with ``--binary`` or a ``.bunv`` name)
UFF file                  ``.h5``                datasets 58 -> FRF file
model file (``.h5``)      ``.uff`` / ``.unv``    modes of M, C, K as datasets 55
``RESULT.json``           ``.uff`` / ``.unv``    identified modes (``ssidlab identify``) as 55
========================  =====================  ==============================================

Bad input raises :class:`ssid.errors.InputError`; ``ssidlab.cli.main`` prints it as one line
and exits with status 2. See ``docs/exchange.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
from typing import Any

from ssid.errors import InputError
from ssidlab.argtypes import check_output_paths

__all__ = [
    "HDF5_EXTENSIONS",
    "UFF_EXTENSIONS",
    "add_convert_subcommand",
    "read_geometry_csv",
    "run_convert",
]

HELP = "Convert between UFF (universal file) and ssidlab's HDF5 FRF/model and result JSON files."
UFF_EXTENSIONS = (".uff", ".unv", ".bunv", ".uf")
HDF5_EXTENSIONS = (".h5", ".hdf5", ".hdf")


def add_convert_subcommand(sub: Any) -> argparse.ArgumentParser:
    """Add the ``convert`` subparser to ``sub`` (an argparse subparsers action); returns it."""
    p = sub.add_parser("convert", prog="ssidlab convert", help=HELP, description=HELP,
                       allow_abbrev=False)
    p.add_argument("input", metavar="IN",
                   help="FRF or model file (.h5), identify's RESULT.json, or a UFF file")
    p.add_argument("output", metavar="OUT",
                   help=f"target: UFF ({', '.join(UFF_EXTENSIONS)}) or FRF file (.h5)")
    p.add_argument("--binary", action="store_true",
                   help="FRFs to UFF: binary 58b (float64, exact) instead of ASCII 58 "
                   "(12 significant digits, frequencies 6)")
    p.add_argument("--geometry", metavar="NODES.csv",
                   help="to UFF: node coordinates in metres, one 'node,x,y,z' per line, "
                   "written as dataset 2411")
    p.add_argument("--quiet", action="store_true", help="do not print the summary line")
    p.set_defaults(run=run_convert)
    return p


# ----------------------------------------------------------------------------------------------
# Run
# ----------------------------------------------------------------------------------------------


def run_convert(args: argparse.Namespace) -> int:
    """Carry out ``ssidlab convert``; returns 0, raises InputError on bad input."""
    out_kind = _output_kind(args.output)
    check_output_paths([args.input], [args.output])
    in_kind = _input_kind(args.input)
    binary = bool(args.binary) or Path(args.output).suffix.lower() == ".bunv"
    if out_kind == "frf-h5" and (args.binary or args.geometry):
        raise InputError("--binary and --geometry apply to UFF output only")
    if in_kind in ("model", "result") and args.binary:
        raise InputError("--binary applies to FRFs (58b); mode shapes (dataset 55) are ASCII")
    geometry = read_geometry_csv(args.geometry) if args.geometry else None

    from ssid.exchange import (
        modes_from_model,
        modes_from_result,
        read_uff_frf,
        write_uff_frf,
        write_uff_modes,
    )
    from ssid.io import read_frf, read_model, write_frf

    if in_kind == "frf" and out_kind == "uff":
        frf = read_frf(args.input)
        n_written = write_uff_frf(args.output, frf, binary=binary, geometry=geometry)
        n_pairs = frf.n_out * frf.n_in
        summary = (f"{n_written} FRFs" + (f" (of {n_pairs}: the others are blanked)" if n_written < n_pairs else "")
                   + (", coherence" if frf.coherence is not None else "")
                   + (f", {frf.n_react * frf.n_in} reactions" if frf.n_react else "")
                   + f", {frf.n_freq} lines as UFF {'58b (binary)' if binary else '58 (ASCII)'}")
    elif in_kind == "uff" and out_kind == "frf-h5":
        frf = read_uff_frf(args.input)
        write_frf(args.output, frf)
        blanked = 0 if frf.valid is None else int((~frf.valid).sum())
        summary = (f"FRF file with {frf.n_out} outputs x {frf.n_in} inputs, {frf.n_freq} lines"
                   + (f", {blanked} blanked values" if blanked else ""))
    elif in_kind == "model" and out_kind == "uff":
        model = read_model(args.input)
        modes = modes_from_model(model.M, model.C, model.K, model.dofs, source=args.input)
        write_uff_modes(args.output, modes, geometry=geometry)
        summary = f"{modes.natural_freq_hz.size} modes of the model as UFF 55"
    elif in_kind == "result" and out_kind == "uff":
        result = _read_json(args.input)
        modes = modes_from_result(result, source=args.input)
        if modes.natural_freq_hz.size == 0:
            raise InputError(f"{args.input}: no mode with a determined frequency and damping")
        write_uff_modes(args.output, modes, geometry=geometry)
        summary = f"{modes.natural_freq_hz.size} identified modes as UFF 55"
        # Modes keep their numbers in RESULT.json; say which numbers are missing and why.
        left_out = sorted(set(range(1, len(result["natural_freq_hz"]) + 1))
                          - set(modes.numbers().tolist()))
        if left_out:
            summary += (f" (numbered as in {Path(args.input).name}; left out, undetermined "
                        f"frequency, damping or shape: mode{'s' * (len(left_out) > 1)} "
                        f"{', '.join(map(str, left_out))})")
    else:
        names = {"frf": "an FRF file", "model": "a model file", "result": "a result JSON",
                 "uff": "a UFF file", "frf-h5": "an HDF5 FRF file"}
        raise InputError(f"cannot convert {names[in_kind]} ({args.input}) to "
                         f"{names[out_kind]} ({args.output}): convert goes between UFF and "
                         "FRF files, or from a model / result to UFF")
    if not args.quiet:
        print(f"wrote {args.output}: {summary}")
    return 0


def _output_kind(path: str) -> str:
    ext = Path(path).suffix.lower()
    if ext in UFF_EXTENSIONS:
        return "uff"
    if ext in HDF5_EXTENSIONS:
        return "frf-h5"
    raise InputError(f"{path}: cannot tell the output format from the extension {ext!r} "
                     f"(UFF: {', '.join(UFF_EXTENSIONS)}; FRF file: {', '.join(HDF5_EXTENSIONS)})")


def _input_kind(path: str) -> str:
    """``frf``, ``model``, ``result`` or ``uff``, from the file's content."""
    if not os.path.exists(path):
        raise InputError(f"{path}: no such file")
    if not os.path.isfile(path):
        raise InputError(f"{path}: not a file")
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise InputError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return _hdf5_kind(path)
    text = head.lstrip()
    if text.startswith(b"{") or Path(path).suffix.lower() == ".json":
        return "result"
    if text.startswith(b"-1") or Path(path).suffix.lower() in UFF_EXTENSIONS:
        return "uff"
    raise InputError(f"{path}: not a recognised input (an ssidlab HDF5 FRF or model file, a "
                     "result JSON, or a UFF file starting with a '    -1' line)")


def _hdf5_kind(path: str) -> str:
    from ssid.io import FRF_FORMAT, MODEL_FORMAT, read_format

    kind = read_format(path)
    if kind == FRF_FORMAT:
        return "frf"
    if kind == MODEL_FORMAT:
        return "model"
    raise InputError(f"{path}: HDF5 file of format {kind or ''!r}; expected an ssidlab FRF or model file")


def _read_json(path: str) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable JSON file ({exc})") from None


def read_geometry_csv(path: str) -> dict[int, tuple[float, float, float]]:
    """Node coordinates from a text file of ``node,x,y,z`` rows (commas or blanks).

    A first row that is not numeric (a header) and lines starting with ``#`` are skipped.
    """
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the geometry file ({exc})") from None
    out: dict[int, tuple[float, float, float]] = {}
    for number, line in enumerate(lines, start=1):
        fields = line.replace(",", " ").replace(";", " ").split()
        if not fields or fields[0].startswith("#"):
            continue
        try:
            node = int(fields[0])
            xyz = tuple(float(v) for v in fields[1:])
        except ValueError:
            if not out and number == 1:
                continue  # header row
            raise InputError(f"{path}:{number}: expected 'node,x,y,z', got {line.strip()!r}") from None
        if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz) or node < 1:
            raise InputError(f"{path}:{number}: expected 'node,x,y,z' with node >= 1 and finite "
                             f"coordinates, got {line.strip()!r}")
        if node in out:
            raise InputError(f"{path}:{number}: node {node} is given twice")
        out[node] = xyz  # type: ignore[assignment]
    if not out:
        raise InputError(f"{path}: no node coordinates found")
    return out
