"""Low-level UFF access through pyuff: tolerant reading, atomic and standard-conforming writing.

pyuff (https://github.com/ladisk/pyuff) parses and formats the datasets. This module adds what
ssidlab needs around it:

* every failure becomes a one-line :class:`ssid.errors.InputError` naming the file and the
  dataset;
* numbers written by Fortran programs with ``D`` exponents (``1.25D+02``) and data lines
  padded with trailing blanks are normalised before pyuff sees them (pyuff's float parsing
  accepts neither in dataset 58);
* datasets are written one at a time to small scratch files and concatenated, because pyuff
  re-scans the whole file after every dataset it appends (quadratic in the file size);
* the byte count of each binary 58b header is corrected: pyuff 2.5 writes ``num_pts * 8``
  whatever the layout, while the data hold 2 or 3 doubles per point for complex or uneven
  data, and other programs read exactly the byte count the header gives;
* the target is written under a temporary name and renamed, like the HDF5 writers.
"""

from __future__ import annotations

import os
import re
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ssid.errors import InputError
from ssid.files import written_atomically

__all__ = ["PYUFF_REQUIREMENT", "read_datasets", "write_datasets"]

PYUFF_REQUIREMENT = "pyuff>=2.5.8,<3"

_DELIM = re.compile(rb"^ {4}-1\s*$")
# A line of numbers only (digits, signs, points, exponent letters, blanks).
_NUMERIC_LINE = re.compile(rb"[0-9.+\-EeDd \t]*")
# A Fortran double-precision exponent letter between a mantissa and its exponent.
_D_EXPONENT = re.compile(rb"(?<=[0-9.])[Dd](?=[+-]?[0-9])")


def _pyuff(src: str) -> Any:
    try:
        import pyuff
    except ImportError:
        raise InputError(f"{src}: UFF files need pyuff (pip install '{PYUFF_REQUIREMENT}')") from None
    return pyuff


def _err(src: str, problem: str) -> InputError:
    return InputError(" ".join(f"{src}: {problem}".splitlines()))


# ----------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------


def _normalise(raw: bytes) -> tuple[bytes, bool, list[int]]:
    """``D`` exponents -> ``E`` and trailing blanks removed, on numeric lines of ASCII datasets
    and on the ``-1`` delimiter lines.

    Binary (58b) datasets are left byte for byte: their payload is not text. The flag is True
    when the file ends inside a dataset (no closing ``-1``: a truncated file). The list holds
    the line number (from 1) of each dataset's opening ``-1``, for messages that point at a
    line; lines are only edited, never added or removed, so the numbers are the file's.
    """
    lines = raw.splitlines(keepends=True)
    out = []
    starts: list[int] = []
    in_block = False
    binary = False
    expect_type = False
    for number, line in enumerate(lines, start=1):
        body = line.rstrip(b"\r\n")
        ending = line[len(body):]
        if in_block and binary:
            # pyuff and most programs put the closing "    -1" right after the payload.
            out.append(line)
            if body.endswith(b"    -1"):
                in_block = binary = False
            continue
        if _DELIM.match(body):
            in_block = not in_block
            expect_type = in_block
            if in_block:
                starts.append(number)
            # Without its trailing blanks: pyuff takes "    -1" followed by blanks for a
            # delimiter only when they reach column 80, and otherwise pairs the others wrongly
            # (datasets after it were lost without a word).
            out.append(b"    -1" + ending)
            continue
        if expect_type:
            # "    58b ..." marks a binary dataset: nothing in it is touched.
            binary = body[6:7].lower() == b"b"
            expect_type = False
            out.append(line)
            continue
        if in_block and b"." in body and _NUMERIC_LINE.fullmatch(body):
            body = _D_EXPONENT.sub(b"E", body).rstrip()
            line = body + ending
        out.append(line)
    return b"".join(out), in_block, starts


def read_datasets(path: str | os.PathLike, *, types: Iterable[int] | None = None) -> list[dict]:
    """Read the datasets of a UFF file with pyuff.

    Parameters
    ----------
    path : str or path-like
    types : iterable of int, optional
        Dataset numbers to read (e.g. ``{58, 164}``); others are skipped unread. All when None.

    Returns
    -------
    list of dict
        pyuff's dictionaries in file order, each with ``"type"`` and ``"_index"`` (position of
        the dataset in the file, from 0, for messages) and, where known, ``"_line"`` (line
        number, from 1, of the dataset's opening ``-1``).

    Raises
    ------
    InputError
        Missing or unreadable file, no UFF datasets, or a dataset pyuff cannot parse.
    """
    src = os.fspath(path)
    if not os.path.exists(src):
        raise _err(src, "no such file")
    if not os.path.isfile(src):
        raise _err(src, "not a file")
    try:
        raw = Path(src).read_bytes()
    except OSError as exc:
        raise _err(src, f"cannot read the file ({exc.strerror or exc})") from None
    if raw.startswith(b"\x89HDF"):
        raise _err(src, "is an HDF5 file, not a UFF (universal) file")
    pyuff = _pyuff(src)
    fixed, unterminated, starts = _normalise(raw)
    if unterminated:
        raise _err(src, "the file ends inside a dataset (no closing '    -1' line): truncated?")
    with tempfile.TemporaryDirectory(prefix="ssidlab-uff-") as tmp:
        name = src
        if fixed != raw:
            name = os.path.join(tmp, "normalised.uff")
            Path(name).write_bytes(fixed)
        try:
            uff = pyuff.UFF(name)
            set_types = [int(t) for t in uff.get_set_types()]
        except Exception as exc:  # noqa: BLE001 -- pyuff raises bare Exception
            raise _err(src, f"not a readable UFF file ({exc})") from None
        if not set_types:
            raise _err(src, "not a UFF file: no datasets delimited by '    -1' lines found")
        wanted = None if types is None else set(types)
        # Our pairing of the delimiters is pyuff's when it finds as many datasets; only then
        # can a message point at a line of the file.
        lines_known = len(starts) == len(set_types)
        out = []
        for index, set_type in enumerate(set_types):
            if wanted is not None and set_type not in wanted:
                continue
            try:
                dset = uff.read_sets(index)
            except Exception as exc:  # noqa: BLE001
                detail = str(exc).replace("Error when reading data-set(s).", "").strip()
                raise _err(src, f"dataset {index + 1} (type {set_type}) is malformed"
                                + (f" ({detail})" if detail else "")) from None
            if not isinstance(dset, dict):
                raise _err(src, f"dataset {index + 1} (type {set_type}) is malformed")
            dset["_index"] = index
            if lines_known:
                dset["_line"] = starts[index]
            out.append(dset)
    return out


# ----------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------


def _fix_58b_byte_count(chunk: bytes) -> bytes:
    """Set the byte-count field of a binary 58b header to the bytes actually written."""
    lines = chunk.split(b"\n", 2)
    header = lines[1]
    if header[6:7].lower() != b"b":
        return chunk
    # Layout (pyuff and the standard): I6, A1 'b', I6 byte order, I6 format, I12 ASCII lines,
    # I12 bytes, ... The ASCII part is the 11 records after the header line.
    rest = lines[2]
    pos = 0
    for _ in range(11):
        pos = rest.index(b"\n", pos) + 1
    payload = len(rest) - pos - len(b"    -1\n")
    fixed = header[:31] + b"%12i" % payload + header[43:]
    return b"\n".join([lines[0], fixed, rest])


def _os_error_within(exc: BaseException) -> OSError | None:
    """The OSError an exception was raised in handling of (its ``__context__`` chain), if any."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, OSError):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def write_datasets(path: str | os.PathLike, datasets: list[dict]) -> None:
    """Write pyuff dataset dictionaries to a new UFF file (replacing any file at ``path``).

    Raises
    ------
    InputError
        pyuff is missing.
    OSError
        The file cannot be created or written (a full disk, also when pyuff meets it).
    RuntimeError
        pyuff refuses a dataset (a bug in the caller: inputs are validated before).
    """
    src = os.fspath(path)
    pyuff = _pyuff(src)
    with written_atomically(src) as tmp_target, tempfile.TemporaryDirectory(prefix="ssidlab-uff-") as tmp, \
            open(tmp_target, "wb") as out:
        scratch = os.path.join(tmp, "one.uff")
        for k, dset in enumerate(datasets):
            if os.path.exists(scratch):
                os.remove(scratch)
            try:
                with warnings.catch_warnings():
                    # pyuff's 58b writer leaves a file object for the collector to close.
                    warnings.simplefilter("ignore", ResourceWarning)
                    pyuff.UFF(scratch).write_sets(dict(dset), mode="add")
            except Exception as exc:
                disk = _os_error_within(exc)
                if disk is not None:  # pyuff wraps a failed write (a full disk) in a bare Exception
                    raise disk from exc
                raise RuntimeError(
                    f"pyuff could not write dataset {k + 1} (type {dset.get('type')}): {exc}"
                ) from exc
            chunk = Path(scratch).read_bytes()
            if dset.get("type") == 58 and dset.get("binary"):
                chunk = _fix_58b_byte_count(chunk)
            out.write(chunk)
