"""The frequency grid of a UFF file's functions: one line per frequency, however it was written.

Each dataset 58 carries its own abscissa, stored to the precision of its format (below). Two
functions measured on one grid may therefore give a line as ``0.333333`` (an uneven ASCII
abscissa, ``E13.5``) and ``0.33333300000000001`` (an even abscissa, ``min + k * inc`` with
``inc`` written as ``3.33333e-01``): the same line. :func:`frequency_grid` merges values of
different functions that agree within what their formats can carry and warns when the
functions truly lie on different grids. Reasons in ``docs/exchange.md`` ("Frequency grid").

How far a stored abscissa value may be from the frequency it stands for:

=====================================  ======================================================
abscissa                               bound (``u(v)``: one unit in the 6th significant digit
                                       of ``v``, i.e. ``10**(floor(log10|v|) - 5)``)
=====================================  ======================================================
uneven, ASCII (``E13.5``)              ``u(x) / 2``
uneven, binary float32 (data types     ``2**-24 |x|`` (half a float32 ulp)
2, 5)
uneven, binary float64 (4, 6)          ``1e-12 max|x|`` (a few ulp; what the reader allowed
                                       before)
even, ASCII or binary (record 7 is     ``u(min) / 2 + k u(inc) / 2`` at line ``k``
``E13.5`` text in both)
=====================================  ======================================================
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from ssid.errors import InputError

from .uff import UFFWarning

__all__ = ["abscissa_tolerance", "frequency_grid"]

# Gap below which float64 abscissae are the same line (a few ulp: even-spaced abscissae
# computed as min + k * inc by different readers).
_FLOAT64_RTOL = 1e-12
_FLOAT32_RTOL = 2.0**-24
# Two values exactly the sum of their bounds apart are two lines: adjacent E13.5 values (one
# unit of the 6th digit, 1000.01 and 1000.02 Hz) are that far apart, and a frequency written
# twice in E13.5 is written alike. Merged, interleaved grids 0.01 Hz apart at 1 kHz lost half
# their lines, each function's values put on the other's (QA). (1e-6: float64 round-off of the
# difference.)
_EDGE = 1.0 - 1e-6
# Single-precision binary data types (real, complex); 4 and 6 are double precision.
_SINGLE = (2, 5)


def _half_unit(v: np.ndarray) -> np.ndarray:
    """Half a unit in the 6th significant digit of each value (0 for 0): E13.5 rounding."""
    v = np.abs(np.asarray(v, dtype=float))
    exponent = np.floor(np.log10(np.where(v > 0, v, 1.0)))
    return np.where(v > 0, 0.5 * 10.0 ** (exponent - 5), 0.0)


def abscissa_tolerance(d: dict, x: np.ndarray) -> np.ndarray:
    """How far each abscissa value of dataset 58 ``d`` (file units, as pyuff read them) may
    be from the frequency it was written for, by its format (table of the module)."""
    x = np.asarray(x, dtype=float)
    ulps = _FLOAT64_RTOL * float(np.abs(x).max(initial=0.0))
    if d.get("abscissa_spacing") == 1:
        k = np.arange(x.size)
        x0, inc = float(d.get("abscissa_min") or 0.0), float(d.get("abscissa_inc") or 0.0)
        return _half_unit(x0) + k * _half_unit(inc) + ulps
    if not d.get("binary"):
        return _half_unit(x) + ulps
    if d.get("ord_data_type") in _SINGLE:
        return _FLOAT32_RTOL * np.abs(x) + ulps
    return np.full(x.size, ulps)


def frequency_grid(src: str, functions: list[Any]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The lines (> 0 Hz) of all functions and each function's line indices (-1: dropped).

    Parameters
    ----------
    src : str
        The file, for messages.
    functions : list of uff_read._Function
        Each with ``x`` (Hz, strictly increasing), ``x_tol`` (Hz, same shape: how far each
        value may be from its true frequency), ``index`` (dataset) and ``even`` (an even
        abscissa: the function has every line of its range).

    Returns
    -------
    freq : (n_freq,) float
        One value per line, that of the most precisely stored function holding it.
    lines : list of (n_k,) int arrays
        For each function, the line of each of its values; -1 for a line at or below 0 Hz.

    Notes
    -----
    Values of different functions are one line when they differ by less than the sum of
    their bounds; two values of one function never are (each is a line of its own). A line
    missing from a function on an even grid within its range means that the grids differ
    (an even grid cannot leave a line out, an uneven one leaves out its blanked values), and
    is warned of; its values there are blanked like any missing value.
    """
    x = np.concatenate([f.x for f in functions])
    tol = np.concatenate([f.x_tol for f in functions])
    owner = np.concatenate([np.full(f.x.size, k) for k, f in enumerate(functions)])
    order = np.argsort(x, kind="stable")
    line_of = np.empty(x.size, dtype=int)
    values: list[float] = []
    best_tol: list[float] = []
    members: set[int] = set()
    for i in order:
        # The current line takes the value if it is within both bounds of the line's most
        # precise value and its function has no value on that line yet.
        if values and owner[i] not in members and x[i] - values[-1] < (tol[i] + best_tol[-1]) * _EDGE:
            if tol[i] < best_tol[-1]:
                values[-1], best_tol[-1] = float(x[i]), float(tol[i])
        else:
            values.append(float(x[i]))
            best_tol.append(float(tol[i]))
            members = set()
        members.add(int(owner[i]))
        line_of[i] = len(values) - 1
    grid = np.array(values)
    positive = grid > 0
    if not positive.any():
        raise InputError(f"{src}: no frequency line above 0 Hz")
    if not positive.all():
        warnings.warn(f"{src}: dropped {int((~positive).sum())} line(s) at or below 0 Hz "
                      "(FRF files hold f > 0 only)", UFFWarning, stacklevel=3)
    new_index = np.cumsum(positive) - 1
    lines, start = [], 0
    for f in functions:
        k = line_of[start:start + f.x.size]
        start += f.x.size
        lines.append(np.where(positive[k], new_index[k], -1))
    _warn_of_different_grids(src, functions, line_of, grid)
    return grid[positive], lines


def _warn_of_different_grids(src: str, functions: list[Any], line_of: np.ndarray,
                             grid: np.ndarray) -> None:
    """Warn when a function on an even grid lacks lines that others give within its range."""
    start = 0
    for f in functions:
        own = line_of[start:start + f.x.size]
        start += f.x.size
        if not f.even:
            continue
        lacking = (own[-1] - own[0] + 1) - own.size
        if lacking > 0:
            step = (f.x[-1] - f.x[0]) / max(f.x.size - 1, 1)
            warnings.warn(f"{src}: the functions are on different frequency grids: dataset "
                          f"{f.index + 1} ({f.x[0]:g} to {f.x[-1]:g} Hz in steps of {step:g} Hz) "
                          f"lacks {lacking} line(s) within its range that other functions give "
                          "(further from its own than their formats' rounding); the lines of "
                          "all are kept, the values a function lacks blanked", UFFWarning,
                          stacklevel=4)
            return
