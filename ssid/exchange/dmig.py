"""Nastran DMIG bulk-data cards (direct matrix input at grid points), written by hand.

Format written (large-field fixed format, MSC/NX Nastran Quick Reference Guide, DMIG):

* a header card per matrix::

    DMIG*   NAME            0               IFO             2
    *       0

  ``IFO`` 6 (symmetric) or 1 (square, for a non-symmetric damping matrix); ``TIN = 2`` real
  double precision input; ``TOUT = 0`` (output precision from the run's PRECISION cell);
* one column card per non-zero column ``(GJ, CJ)``, then one continuation per non-zero term
  ``(Gi, Ci, Ai)`` (the imaginary part ``Bi`` is blank for real matrices)::

    DMIG*   NAME            GJ              CJ
    *       Gi              Ci              Ai

* fields are 16 characters, left-justified; continuations begin with ``*`` in column 1 and
  carry no continuation identifiers (automatic continuation, as Nastran and pyNastran accept);
* numbers in Fortran double-precision form ``-1.2345678901D+3``: 11 significant digits (10
  for two-digit exponents);
* a symmetric matrix gives only its upper triangle (rows ``i <= j`` of column ``j``), of
  ``(A + A^T) / 2``; zero terms are left out.

A DOF ``"<grid><+|-><dir>"`` is grid point ``grid``, component 1-6; a bare ``"<n>"`` is scalar
point ``n`` (component 0). A ``-`` label is the grid's axis reversed, so its rows and columns
change sign (``A'_ij = s_i s_j A_ij``); the file therefore always holds ``+`` components.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence

import numpy as np

from ssid.errors import InputError
from ssid.files import written_atomically

from .labels import labels_to_node_dirs

__all__ = ["NASTRAN_NAME", "dmig_cards", "format_dmig", "grid_components", "write_dmig"]

#: A Nastran matrix (data block) name: a letter and up to 7 letters or digits.
NASTRAN_NAME = re.compile(r"[A-Z][A-Z0-9]{0,7}")
_FIELD = 16


def grid_components(src: str, dofs: Sequence[str], target: str) -> tuple[np.ndarray, np.ndarray]:
    """``(n, 2)`` integer ``[grid, component]`` rows and the sign of each DOF.

    Raises
    ------
    InputError
        A label without node+direction form, two labels on one grid component, or one ID
        both a scalar point (``"7"``) and a grid (``"7+X"``): Nastran numbers GRID and
        SPOINT points in one space ("all scalar point identification numbers must be unique
        with respect to all other structural, scalar, and fluid points", SPOINT remarks), so
        the model could not be defined, and a reader of ``[7, 0]`` and ``[7, 1]`` could not
        tell whether 7 is a grid or a scalar point.
    """
    node_dirs = labels_to_node_dirs(src, dofs, "dofs", target)
    pairs = np.array([[n, abs(d)] for n, d in node_dirs], dtype=np.int64).reshape(-1, 2)
    signs = np.array([-1.0 if d < 0 else 1.0 for _, d in node_dirs])
    seen: dict[tuple[int, int], str] = {}
    kind_of: dict[int, tuple[bool, str]] = {}  # ID -> (scalar point?, first label)
    for label, (g, c) in zip(dofs, pairs.tolist()):
        if (g, c) in seen:
            raise InputError(f"{src}: DOFs {seen[(g, c)]!r} and {label!r} are the same grid "
                             f"component ({g}, {c}) in {target}")
        seen[(g, c)] = label
        scalar, first = kind_of.setdefault(g, (c == 0, label))
        if scalar != (c == 0):
            spoint, grid = (first, label) if scalar else (label, first)
            raise InputError(f"{src}: DOFs {spoint!r} (scalar point {g}) and {grid!r} (grid "
                             f"{g}) use one ID for an SPOINT and a GRID, which Nastran requires "
                             f"to be distinct; give the scalar point a number no grid uses")
    return pairs, signs


def _real(x: float) -> str:
    """``x`` as a Fortran double-precision constant that fits a 16-character field."""
    if x == 0.0:
        return "0.0D+0"
    for decimals in range(_FIELD - 4, -1, -1):
        mantissa, exponent = f"{x:.{decimals}E}".split("E")
        text = f"{mantissa}D{int(exponent):+d}"
        if len(text) <= _FIELD:
            return text
    raise ValueError(f"cannot format {x!r} in {_FIELD} characters")  # pragma: no cover


def _card(fields: list[str]) -> list[str]:
    """A large-field DMIG* card: 4 fields per line, '*' continuation lines."""
    lines = []
    for k in range(0, len(fields), 4):
        head = "DMIG*   " if k == 0 else "*       "
        lines.append((head + "".join(f"{f:<{_FIELD}}" for f in fields[k:k + 4])).rstrip())
    return lines


def dmig_cards(name: str, A: np.ndarray, pairs: np.ndarray, *, symmetric: bool) -> list[str]:
    """The DMIG lines of one real matrix over ``pairs`` (already sign-adjusted)."""
    A = np.asarray(A, dtype=float)
    if symmetric:
        A = (A + A.T) / 2
    lines = _card([name, "0", "6" if symmetric else "1", "2", "0"])
    for j in range(A.shape[1]):
        rows = np.flatnonzero(A[: j + 1, j] if symmetric else A[:, j])
        if rows.size == 0:
            continue
        fields = [name, str(pairs[j, 0]), str(pairs[j, 1]), ""]
        for i in rows:
            fields += [str(pairs[i, 0]), str(pairs[i, 1]), _real(float(A[i, j])), ""]
        lines += _card(fields)
    return lines


def format_dmig(matrices: Sequence[tuple[str, np.ndarray, bool]], dofs: Sequence[str],
                src: str = "DMIG", notes: Sequence[str] = ()) -> str:
    """Bulk-data text with one DMIG matrix per ``(name, A, symmetric)``.

    ``notes`` are extra comment lines for the head of the file.

    Raises
    ------
    InputError
        A bad matrix name, a matrix that is not (n, n) real and finite, or bad labels.
    """
    pairs, signs = grid_components(src, list(dofs), "Nastran DMIG")
    n = len(dofs)
    head = ["$ ssidlab DMIG export: large-field DMIG* cards, TIN=2 (real double),",
            "$ IFO=6 symmetric (upper triangle) or IFO=1 square"]
    head += [f"$ {line}" for line in notes]
    head += ["$ DOFs (label -> grid, component):"]
    head += [f"$   {lbl} -> {g}, {c}" for lbl, (g, c) in zip(dofs, pairs.tolist())]
    body = []
    for name, A, symmetric in matrices:
        if not NASTRAN_NAME.fullmatch(name):
            raise InputError(f"{src}: {name!r} is not a Nastran matrix name (a letter and up "
                             "to 7 upper-case letters or digits)")
        A = np.asarray(A)
        if A.shape != (n, n) or A.dtype.kind not in "fiu" or not np.all(np.isfinite(A)):
            raise InputError(f"{src}: matrix {name} must be real, finite, {n} x {n}")
        body += [f"$ matrix {name}"] + dmig_cards(name, signs[:, None] * A * signs[None, :],
                                                  pairs, symmetric=symmetric)
    return "\n".join(head + body) + "\n"


def write_dmig(path: str | os.PathLike, matrices: Sequence[tuple[str, np.ndarray, bool]],
               dofs: Sequence[str], notes: Sequence[str] = ()) -> None:
    """Write :func:`format_dmig` text to ``path`` (via a temporary file and a rename)."""
    src = os.fspath(path)
    text = format_dmig(matrices, dofs, src, notes)
    with written_atomically(src) as tmp:
        tmp.write_text(text, encoding="ascii")
