"""Reading FRFs and coherence from UFF dataset 58 / 58b (pyuff): :func:`read_uff_frf`.

The mapping is :mod:`ssid.exchange.uff`'s (and ``docs/exchange.md``), read back: one function
per (output, input) pair, blanked lines absent or NaN, coherence and reactions by function and
ordinate type, the axes' units converted to SI.
"""

from __future__ import annotations

import itertools
import os
import warnings
from dataclasses import dataclass

import numpy as np

from ssid.errors import InputError
from ssid.frf import FRFData
from ssid.io import validate_frf

from ._uffio import read_datasets
from .labels import format_dof_label
from .uff import FUNC_COHERENCE, FUNC_FRF, FUNC_MULTIPLE_COHERENCE, UFFWarning
from .uff_coherence import OUTPUT_ONLY, is_multiple, select_coherence
from .uff_grid import abscissa_tolerance, frequency_grid
from .uff_units import SPEC_FREQUENCY, SPEC_GENERAL, SPEC_NAMES, SPEC_REACTION, FileUnits

__all__ = ["read_uff_frf"]

# Single-precision files round coherence near 1 to values like 1.000001.
_COHERENCE_ROUNDING = 1e-6


@dataclass
class _Function:
    kind: str  # "frf", "coherence" or "reaction"
    index: int
    rsp: str
    ref: str
    x: np.ndarray
    y: np.ndarray
    x_tol: np.ndarray  # Hz: how far each x may be from its frequency (format's rounding)
    even: bool  # an even abscissa (min + k * inc): no line of its range left out
    multiple: bool = False  # a coherence that is the output's multiple coherence


class _Unplaced(Exception):
    """A coherence dataset whose response or reference is no DOF (message: why)."""


def read_uff_frf(path: str | os.PathLike) -> FRFData:
    """Read FRFs, coherence and reactions from the datasets 58 of a UFF file.

    Parameters
    ----------
    path : str or path-like
        ASCII and/or binary UFF file, e.g. written by :func:`write_uff_frf` or another program.

    Returns
    -------
    FRFData
        Validated accelerances in SI. Outputs and inputs are in order of first appearance,
        labels ``"<node><+|-><dir>"``. Values missing from a function, or NaN, are blanked
        (``valid`` False, ``H`` NaN); ``valid`` is None when nothing is blanked.

    Notes
    -----
    * Function type 4 with ordinate acceleration (12) is taken as is; velocity (11) and
      displacement (8) FRFs are converted with ``j omega`` and ``-omega^2``; an unknown
      ordinate type (0 or 1) is what its unit label says, else acceleration, with a warning;
      ordinate reaction force (9) makes an interface reaction. Function types 6 and 26 are
      coherence, ordinary or multiple (:mod:`ssid.exchange.uff_coherence`: the multiple one
      wins; with several inputs an ordinary one is left out with a warning; one that cannot
      be placed is left out with a warning). Others are skipped with a warning.
    * Units (:mod:`ssid.exchange.uff_units`): a recognised axis unit label (``g``,
      ``in/s^2``, ``lbf``, ``rad/s`` on the abscissa; an ordinate ``Gs/N`` gives both the
      ordinate's and the denominator's) gives its axis's unit, and wins over a
      dataset 164 that disagrees (with a warning); an axis without one is in the units of the
      dataset 164 (SI without one): ``H * force_factor / length_factor`` for a translation
      per force, a rotation (radians) taking no factor and a moment the force factor times
      the length factor. An unrecognised FRF label is refused (its scale cannot be known);
      unrecognised abscissa labels are reported in one warning. An FRF must be per
      force (denominator type 13, or a force label; an unknown one is taken so, with a
      warning).
    * Lines at or below 0 Hz are dropped with a warning (the FRF file needs f > 0). Values
      of different functions that differ only by their abscissa formats' rounding are one
      line; truly different grids are warned of (:mod:`ssid.exchange.uff_grid`).

    Raises
    ------
    InputError
        Unreadable or malformed file, no FRF, inconsistent functions (duplicates, real FRFs,
        a non-frequency abscissa, a unit label contradicting its axis's data type or DOF), or
        data the FRF file layout refuses.
    """
    src = os.fspath(path)
    datasets = read_datasets(path, types={58, 164})
    units = FileUnits.of(src, datasets)
    functions = [d for d in datasets if d["type"] == 58]
    if not functions:
        raise InputError(f"{src}: no function datasets (58) in the file")
    frfs, cohs, reacts = [], [], []
    skipped = unknown_units = 0
    for d in functions:
        ftype = d.get("func_type")
        if ftype == FUNC_FRF:
            kind = "reaction" if d.get("ordinate_spec_data_type") == SPEC_REACTION else "frf"
            f = _read_function(src, d, kind, units)
            factor, known = units.frf_factor(d, kind, f.x)
            finite = np.isfinite(f.y)  # NaN is a blanked value, and stays one
            with np.errstate(over="ignore", invalid="ignore"):
                f.y = f.y * factor
            if not np.isfinite(f.y[finite]).all():
                # Finite in the file's units, infinite in SI: no blank, a value lost.
                raise InputError(f"{src}: {_where(d)}: {f.rsp}/{f.ref} overflows float64 when "
                                 "converted to SI units (values too large)")
            unknown_units += not known
            (reacts if kind == "reaction" else frfs).append(f)
        elif ftype in (FUNC_COHERENCE, FUNC_MULTIPLE_COHERENCE):
            try:
                cohs.append(_read_function(src, d, "coherence", units))
            except _Unplaced as exc:
                # Coherence is optional in the FRF file: the FRFs do not need this dataset.
                warnings.warn(f"{src}: {_where(d)} is a coherence function that cannot be "
                              f"placed ({exc}); left out (the FRFs are read without it)",
                              UFFWarning, stacklevel=2)
        else:
            skipped += 1
    if not frfs:
        raise InputError(f"{src}: no FRF (dataset 58 with function type 4) among "
                         f"{len(functions)} function dataset(s)")
    if skipped:
        warnings.warn(f"{src}: skipped {skipped} dataset(s) 58 that are neither FRFs nor "
                      "coherence", UFFWarning, stacklevel=2)
    if unknown_units:
        warnings.warn(f"{src}: {unknown_units} FRF(s) do not say what the ordinate or the "
                      "denominator is (specific data type 0/1, no known unit label); taken as "
                      "acceleration (or reaction force) per force", UFFWarning, stacklevel=2)
    for message in units.warnings():
        warnings.warn(message, UFFWarning, stacklevel=2)

    _fold_opposite_directions(frfs + cohs + reacts)
    outputs = _merged_order(frfs + cohs, "rsp", "ref")
    inputs = _merged_order(frfs + cohs, "ref", "rsp")
    _refuse_inputs_not_measured(src, outputs, inputs)
    cohs = select_coherence(src, cohs, inputs)
    freq, lines = frequency_grid(src, frfs + cohs + reacts)
    nf, nc = len(frfs), len(cohs)
    H, have = _assemble(src, frfs, outputs, inputs, lines[:nf], freq.size, "FRF")
    valid = have & ~np.isnan(H)
    coherence = _coherence(src, cohs, outputs, inputs, lines[nf:nf + nc], freq.size, valid)
    reactions = _merged_order(reacts, "rsp", "ref", "reaction") or None
    H_reaction = None
    if reacts:
        stray = [f.ref for f in reacts if f.ref not in inputs]
        if stray:
            raise InputError(f"{src}: reaction function with reference {stray[0]!r}, which is "
                             "not an input of any FRF")
        H_reaction, have_r = _assemble(src, reacts, reactions, inputs, lines[nf + nc:],
                                       freq.size, "reaction")
        if not have_r.all():
            k, r, j = (int(v) for v in np.argwhere(~have_r)[0])
            raise InputError(f"{src}: no reaction value for {reactions[r]!r} per input "
                             f"{inputs[j]!r} at {freq[k]:g} Hz; reactions must cover every "
                             "line and input")
    frf = FRFData(freq_hz=freq, H=H, outputs=outputs, inputs=inputs, coherence=coherence,
                  valid=None if valid.all() else valid, H_reaction=H_reaction,
                  reactions=reactions, attrs={"converted_from": os.path.basename(src)})
    return validate_frf(frf, src)


def _fold_opposite_directions(functions: list[_Function]) -> None:
    """Where a file names one DOF in both senses (``4+Z`` somewhere, ``4-Z`` elsewhere: an
    inverted sensor at a driving point, one accelerometer mounted upside down), the ``-``
    labels become the ``+`` ones and the values they carry change sign (coherence excepted).
    Left apart, one DOF became two outputs, or the driving point was refused for want of
    its input among the outputs. A ``-`` label alone stays as written (docs/exchange.md)."""
    labels = {lab for f in functions for lab in (f.rsp, f.ref)}
    flip = {lab for lab in labels if "-" in lab and lab.replace("-", "+") in labels}
    for f in functions:
        n = (f.rsp in flip) + (f.ref in flip)
        if n % 2 and f.kind != "coherence":
            f.y = -f.y
        f.rsp, f.ref = (lab.replace("-", "+") if lab in flip else lab for lab in (f.rsp, f.ref))


def _refuse_inputs_not_measured(src: str, outputs: list[str], inputs: list[str]) -> None:
    """Refuse references that are not responses too, as the FRF file does, saying why, and,
    for a roving-hammer file (every response is also a reference: one accelerometer, the
    hammer moved), that reciprocity gives the FRFs in the layout the file needs."""
    stray = [label for label in inputs if label not in outputs]
    if not stray:
        return
    shown = ", ".join(map(repr, stray[:3])) + (", ..." if len(stray) > 3 else "")
    message = (f"{src}: reference(s) {shown} of {len(inputs)} are not among the "
               f"{len(outputs)} response(s); an FRF file needs each input's driving-point "
               "response measured too (every input is an output)")
    if all(label in inputs for label in outputs):
        # Maxwell-Betti: H(response a, force at b) = H(response b, force at a).
        message += (f". This looks like a roving-hammer test (response(s) "
                    f"{', '.join(map(repr, outputs))}, the hammer at {len(inputs)} points): by "
                    "reciprocity the same FRFs are the responses at the impact points to a "
                    "force at the response DOF(s), which the FRF file takes; swap each "
                    "dataset 58's response and reference (record 6) in the program that "
                    "wrote the file (ssidlab has no tool for it) and convert again")
    raise InputError(message)


def _where(d: dict) -> str:
    return f"dataset {d['_index'] + 1} (58)"


def _merged_order(functions: list[_Function], key: str, group: str,
                  primary: str = "frf") -> list[str]:
    """Labels ``key`` of the FRF functions in an order consistent with every group's file order.

    A pair that is absent (all its values blanked) removes a label from one group's sequence
    (e.g. outputs per input); merging the sequences (a topological sort, ties broken by first
    appearance) still gives the order they were written in. Inconsistent orders (possible in
    other programs' files) fall back to first appearance. Only labels of functions of kind
    ``primary`` are returned; others (coherence) add ordering only.
    """
    labels = {getattr(f, key) for f in functions if f.kind == primary}
    first: dict[str, int] = {}
    sequences: dict[tuple[str, str], list[str]] = {}
    for f in functions:
        label = getattr(f, key)
        if label not in labels:
            continue
        first.setdefault(label, len(first))
        sequences.setdefault((f.kind, getattr(f, group)), []).append(label)
    after: dict[str, set[str]] = {label: set() for label in first}
    for seq in sequences.values():
        for a, b in itertools.pairwise(seq):
            after[a].add(b)
    indegree = {label: 0 for label in first}
    for targets in after.values():
        for b in targets:
            indegree[b] += 1
    ready = sorted((first[label], label) for label, d in indegree.items() if d == 0)
    order: list[str] = []
    while ready:
        _, label = ready.pop(0)
        order.append(label)
        for b in after[label]:
            indegree[b] -= 1
            if indegree[b] == 0:
                ready.append((first[b], b))
        ready.sort()
    return order if len(order) == len(first) else sorted(first, key=first.get)


def _read_function(src: str, d: dict, kind: str, units: FileUnits) -> _Function:
    where = _where(d)
    complex_ = kind != "coherence"
    multiple = not complex_ and is_multiple(d, FUNC_MULTIPLE_COHERENCE)
    try:
        rsp = format_dof_label(d.get("rsp_node", 0), d.get("rsp_dir", 0))
    except ValueError as exc:
        if not complex_:
            raise _Unplaced(f"response {exc}") from None
        raise InputError(f"{src}: {where}: response {exc}") from None
    try:
        # A multiple coherence belongs to its output: written without a reference (node 0).
        ref = (OUTPUT_ONLY if multiple and not d.get("ref_node")
               else format_dof_label(d.get("ref_node", 0), d.get("ref_dir", 0)))
    except ValueError as exc:
        if not complex_:
            raise _Unplaced(f"reference {exc}") from None
        raise InputError(f"{src}: {where}: reference (input) {exc}") from None
    x = np.asarray(d.get("x"), dtype=float).ravel()
    y = np.asarray(d.get("data")).ravel()
    n = d.get("num_pts")
    if n is not None and y.size != int(n):
        raise InputError(f"{src}: {where}: header announces {int(n)} values, the data hold "
                         f"{y.size} (truncated or damaged file)")
    if y.size == 0 or x.shape != y.shape:
        raise InputError(f"{src}: {where}: {x.size} abscissa values for {y.size} data values")
    abscissa = d.get("abscissa_spec_data_type", 0)
    if abscissa not in (0, SPEC_GENERAL, SPEC_FREQUENCY):
        name = SPEC_NAMES.get(abscissa, f"type {abscissa}")
        raise InputError(f"{src}: {where}: abscissa is {name}, not frequency")
    factor = units.abscissa_factor(d)  # Hz per file unit (rad/s, rpm, kHz labels)
    x_tol = abscissa_tolerance(d, x) * abs(factor)
    x = x * factor
    if not np.all(np.isfinite(x)) or np.any(np.diff(x) <= 0):
        raise InputError(f"{src}: {where}: abscissa (frequency) is not finite and strictly "
                         "increasing")
    if complex_ and y.dtype.kind != "c":
        raise InputError(f"{src}: {where}: FRF {rsp}/{ref} is real; an FRF needs complex "
                         "values (magnitude and phase)")
    if not complex_:
        if y.dtype.kind == "c":
            if np.any(y.imag != 0):
                raise InputError(f"{src}: {where}: coherence {rsp}/{ref} is complex")
            y = y.real
        y = y.astype(float)
    _refuse_infinite(src, d, f"{rsp}/{ref}", x, y)
    return _Function(kind, d["_index"], rsp, ref, x, y, x_tol, d.get("abscissa_spacing") == 1,
                     multiple)


# Values per data line of an ASCII dataset 58 (record 12), by ordinate data type (2, 4: real
# single, double; 5, 6: complex single, double) and abscissa spacing (1 even, 0 uneven):
# 6E13.5, 4E20.12, 2(E13.5,E20.12), E13.5,2E20.12 ... as the standard lays them out.
_VALUES_PER_LINE = {(2, 1): 6, (2, 0): 3, (4, 1): 4, (4, 0): 2,
                    (5, 1): 3, (5, 0): 2, (6, 1): 2, (6, 0): 1}


def _refuse_infinite(src: str, d: dict, pair: str, x: np.ndarray, y: np.ndarray) -> None:
    """Refuse an infinite value (``Inf``, or a number beyond float64 such as ``1e+999``).

    A NaN is a blanked value, which the reader keeps as such (``valid`` False); an infinite
    one was blanked too, silently (``Inf`` times a unit factor is ``inf+nanj``), though it is
    no blank but a damaged or overflowing number. The message gives the dataset, the value's
    number and frequency and, for an ASCII dataset laid out as the standard says, its line.
    """
    bad = np.isinf(y.real) | np.isinf(y.imag)
    if not bad.any():
        return
    k = int(np.flatnonzero(bad)[0])
    line = ""
    per_line = _VALUES_PER_LINE.get((d.get("ord_data_type"), d.get("abscissa_spacing")))
    if not d.get("binary") and "_line" in d and per_line:
        # The opening -1, the "58" line and the 11 records of the header come first.
        line = f", line {d['_line'] + 13 + k // per_line}"
    raise InputError(f"{src}: {_where(d)}: value {k + 1} of {pair} (at {x[k]:g} Hz{line}) is "
                     "infinite (Inf, or a number beyond the float64 range such as 1e+999); UFF "
                     "data must be finite")


def _assemble(src: str, functions: list[_Function], rows: list[str], cols: list[str],
              lines: list[np.ndarray], n_freq: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Complex (n_freq, n_rows, n_cols) array (NaN where absent) and where values were given."""
    row, col = {r: i for i, r in enumerate(rows)}, {c: j for j, c in enumerate(cols)}
    out = np.full((n_freq, len(rows), len(cols)), np.nan, dtype=complex)
    have = np.zeros(out.shape, dtype=bool)
    seen: dict[tuple[int, int], int] = {}
    for f, k in zip(functions, lines):
        i, j = row[f.rsp], col[f.ref]
        if (i, j) in seen:
            raise InputError(f"{src}: datasets {seen[(i, j)] + 1} and {f.index + 1} are both "
                             f"the {what} {f.rsp}/{f.ref}")
        seen[(i, j)] = f.index
        keep = k >= 0
        out[k[keep], i, j] = f.y[keep]
        have[k[keep], i, j] = True
    return out, have


def _coherence(src: str, cohs: list[_Function], outputs: list[str], inputs: list[str],
               lines: list[np.ndarray], n_freq: int, valid: np.ndarray) -> np.ndarray | None:
    """Coherence over the FRF grid, or None (with a warning) when it does not cover the FRFs."""
    if not cohs:
        return None
    pairs = [(f, k) for f, k in zip(cohs, lines) if f.rsp in outputs and f.ref in inputs]
    coh_lines = [k for _, k in pairs]
    C, have = _assemble(src, [f for f, _ in pairs], outputs, inputs, coh_lines, n_freq,
                        "coherence")
    if not have[valid].all():
        warnings.warn(f"{src}: coherence does not cover every FRF value; not read",
                      UFFWarning, stacklevel=3)
        return None
    C = np.where(have, C.real, 0.0)  # no coherence where there is no FRF value either
    near = (C > -_COHERENCE_ROUNDING) & (C < 1 + _COHERENCE_ROUNDING)
    return np.where(near, np.clip(C, 0.0, 1.0), C)
