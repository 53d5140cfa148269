"""FRFs and coherence as UFF (universal file) dataset 58, ASCII or binary 58b, through pyuff
(reading them back: :mod:`ssid.exchange.uff_read`).

Mapping (details and the reasons in ``docs/exchange.md``):

* one dataset 58 per (output, input) pair: function type 4 (FRF), response node/direction from
  the output label, reference node/direction from the input label (``"4+Z"`` <-> node 4,
  direction +3); ordinate acceleration (specific data type 12) over excitation force (13),
  abscissa frequency (18) in Hz; complex double precision, uneven abscissa (the frequency of
  every point is stored);
* coherence: function type 6, real; interface reactions: function type 4 with ordinate
  reaction force (9);
* a dataset 164 declares SI units; a dataset 2411 holds node coordinates when they are given;
* blanked values (``valid`` False) are **not written**: each function holds only its valid
  lines, which the uneven abscissa allows. On reading, a line that a function lacks, or a NaN
  value, is blanked again, so the ``valid`` mask survives the round trip. ``H_var``, ``n_avg``
  and the file attributes have no place in dataset 58 and are not written.

Precision: ASCII 58 stores values with 12 significant digits (pyuff writes E20.11) but the
abscissa only with 6 (the standard's E13.5); binary 58b stores both as IEEE float64, exactly.
"""

from __future__ import annotations

import os
import time
import warnings
from typing import Any

import numpy as np

from ssid.errors import InputError
from ssid.frf import FRFData
from ssid.io import validate_frf

from ._uffio import write_datasets
from .labels import labels_to_node_dirs
from .uff_geometry import Geometry, geometry_dataset, si_units_dataset
from .uff_units import (
    SPEC_ACCELERATION,
    SPEC_FORCE,
    SPEC_FREQUENCY,
    SPEC_GENERAL,
    SPEC_REACTION,
)

__all__ = ["UFFWarning", "frf_datasets", "write_uff_frf"]

FUNC_FRF, FUNC_COHERENCE, FUNC_MULTIPLE_COHERENCE = 4, 6, 26


class UFFWarning(UserWarning):
    """Something in a UFF file was converted or left out (shown by the CLI as one line)."""


# ----------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------


def write_uff_frf(
    path: str | os.PathLike,
    frf: FRFData,
    *,
    binary: bool = False,
    geometry: Geometry | None = None,
) -> int:
    """Write FRFs (and coherence, reactions) as a UFF file of datasets 164, [2411,] 58.

    Parameters
    ----------
    path : str or path-like
        Target file (``.uff`` or ``.unv``), replaced if it exists.
    frf : FRFData
        Validated like :func:`ssid.io.write_frf`. Every output, input and reaction label must
        have the node+direction form (:func:`ssid.exchange.labels.parse_dof_label`).
    binary : bool
        Write binary 58b (float64, exact) instead of ASCII 58.
    geometry : mapping of node -> (x, y, z), optional
        Node coordinates in metres, written as dataset 2411.

    Returns
    -------
    int
        FRFs written: a pair blanked throughout (or valid at one line only) has none.

    Raises
    ------
    InputError
        Invalid data, a label without node+direction form, fewer than 2 frequency lines, no
        FRF with two valid lines, or (ASCII only) two lines that the abscissa's 6 significant
        digits cannot tell apart.
    OSError
        The file cannot be created.
    """
    src = os.fspath(path)
    datasets = frf_datasets(src, frf, binary=binary, geometry=geometry)
    write_datasets(path, datasets)
    return sum(map(_is_accelerance, datasets))


def _is_accelerance(d: dict) -> bool:
    """Whether a dataset dictionary of :func:`frf_datasets` is an FRF (not a reaction's)."""
    return d.get("type") == 58 and d["func_type"] == FUNC_FRF and d["ordinate_spec_data_type"] == SPEC_ACCELERATION


def frf_datasets(src: str, frf: FRFData, *, binary: bool = False,
                 geometry: Geometry | None = None) -> list[dict]:
    """The pyuff dataset dictionaries :func:`write_uff_frf` writes (164, [2411,] 58 ...)."""
    data = validate_frf(frf, src)
    target = "UFF dataset 58"
    nodes = dict(zip(data.outputs, labels_to_node_dirs(src, data.outputs, "output", target)))
    _refuse_opposite_senses(src, nodes)
    freq = data.freq_hz
    if freq.size < 2:
        raise InputError(f"{src}: UFF 58 needs at least 2 frequency lines, got {freq.size}")
    if not binary:
        _check_ascii_abscissa(src, freq)
    stamp = time.strftime("%d-%b-%y %H:%M:%S")
    multiple = data.n_in > 1
    out: list[dict] = [si_units_dataset()]
    if geometry:
        out.append(geometry_dataset(src, geometry))

    def function(kind: str, rsp: str, ref: str, x: np.ndarray, y: np.ndarray) -> dict:
        d = _function_dict(kind, nodes[rsp], nodes[ref], x, y, binary, multiple)
        d.update(id1=f"{rsp}/{ref} {d.pop('_what')}"[:80], id2="ssidlab", id3=stamp,
                 func_id=len(out), rsp_ent_name=_entity(rsp), ref_ent_name=_entity(ref))
        return d

    valid = data.valid_mask() & np.isfinite(data.H)
    short = []
    for j, ref in enumerate(data.inputs):
        for i, rsp in enumerate(data.outputs):
            keep = valid[:, i, j]
            # pyuff needs two points per function; a pair with none is simply absent.
            if keep.sum() >= 2:
                out.append(function("frf", rsp, ref, freq[keep], data.H[keep, i, j]))
            elif keep.any():
                short.append(f"{rsp}/{ref}")
    if not any(map(_is_accelerance, out)):
        # The file would hold no FRF, which no reader (ours included) accepts.
        raise InputError(f"{src}: no FRF has two valid lines (values blanked or not finite): "
                         "a UFF 58 file would hold none")
    if data.coherence is not None:
        for j, ref in enumerate(data.inputs):
            for i, rsp in enumerate(data.outputs):
                out.append(function("coherence", rsp, ref, freq, data.coherence[:, i, j]))
    if data.H_reaction is not None:
        for j, ref in enumerate(data.inputs):
            for r, rsp in enumerate(data.reactions or []):
                out.append(function("reaction", rsp, ref, freq, data.H_reaction[:, r, j]))
    if short:
        warnings.warn(f"{src}: {len(short)} FRF(s) with a single valid line not written "
                      f"(UFF 58 needs 2 points), e.g. {short[0]}", UFFWarning, stacklevel=3)
    return out


def _refuse_opposite_senses(src: str, nodes: dict[str, tuple[int, int]]) -> None:
    """Refuse two outputs that are one DOF in UFF 58: ``4+Z`` and ``4-Z``.

    In dataset 58 a DOF is a node and a direction code, and the code's sign is only the sense
    in which that DOF was measured (record 6: direction -3 is -Z): ``4+Z`` and ``4-Z`` are
    the same coordinate, one the negative of the other, not two DOFs. Our reader takes them so
    (``ssid.exchange.uff_read``: one DOF ``4+Z``, the ``-Z`` values negated) and would find
    two functions for each pair, refusing the file; keeping both apart instead would read a
    meaning into the sign that the format does not give it. So such a file is refused here
    rather than written. Inputs and reactions are outputs too: the outputs cover every label.
    """
    seen: dict[tuple[int, int], str] = {}
    for label, (node, direction) in nodes.items():
        if direction == 0:  # a scalar point has no sense, its label is its node alone
            continue
        other = seen.setdefault((node, abs(direction)), label)
        if other != label:
            raise InputError(
                f"{src}: outputs {other!r} and {label!r} are the same DOF in UFF 58 (node {node}, "
                f"direction {abs(direction)}; the sign is only the measuring sense), which cannot "
                "hold both: a reader would take them for one DOF measured twice; leave one out "
                "or give it another node")


def _check_ascii_abscissa(src: str, freq: np.ndarray) -> None:
    """Refuse lines that become equal in the E13.5 abscissa field of an ASCII 58."""
    stored = np.array([float(f"{f:13.5e}") for f in freq])
    same = np.flatnonzero(np.diff(stored) <= 0)
    if same.size:
        k = int(same[0])
        raise InputError(
            f"{src}: frequency lines {freq[k]:.10g} and {freq[k + 1]:.10g} Hz are the same to "
            "the 6 significant digits of an ASCII UFF 58 abscissa (E13.5); write binary 58b")


def _entity(label: str) -> str:
    # Entity names are 10 characters; longer labels are only in ID line 1.
    return label if len(label) <= 10 else "NONE"


def _function_dict(kind: str, rsp: tuple[int, int], ref: tuple[int, int], x: np.ndarray,
                   y: np.ndarray, binary: bool, multiple: bool) -> dict[str, Any]:
    rot_rsp, rot_ref = abs(rsp[1]) > 3, abs(ref[1]) > 3
    force_unit = "N*m" if rot_ref else "N"
    if kind == "frf":
        what, func = "accelerance", FUNC_FRF
        num = (SPEC_ACCELERATION, "Acceleration", "rad/s^2" if rot_rsp else "m/s^2")
        den = (SPEC_FORCE, "Force", force_unit)
        y = np.asarray(y, dtype=complex)
    elif kind == "reaction":
        what, func = "reaction force per input force", FUNC_FRF
        num = (SPEC_REACTION, "Reaction force", "N*m" if rot_rsp else "N")
        den = (SPEC_FORCE, "Force", force_unit)
        y = np.asarray(y, dtype=complex)
    else:
        # pyuff writes only function type 6; with several inputs the values are the multiple
        # coherence of the output, stored against each input (ID line 1 says which).
        what = "multiple coherence" if multiple else "coherence"
        func = FUNC_COHERENCE
        num, den = (SPEC_GENERAL, "Coherence", "NONE"), (0, "NONE", "NONE")
        y = np.asarray(y, dtype=float)
    return {
        "type": 58, "binary": int(binary), "_what": what,
        "id4": "NONE", "id5": "NONE",
        "func_type": func, "ver_num": 0, "load_case_id": 0,
        "rsp_node": int(rsp[0]), "rsp_dir": int(rsp[1]),
        "ref_node": int(ref[0]), "ref_dir": int(ref[1]),
        "abscissa_spacing": 0,
        "abscissa_spec_data_type": SPEC_FREQUENCY, "abscissa_axis_lab": "Frequency",
        "abscissa_axis_units_lab": "Hz",
        "ordinate_spec_data_type": num[0], "ordinate_axis_lab": num[1],
        "ordinate_axis_units_lab": num[2],
        "orddenom_spec_data_type": den[0], "orddenom_axis_lab": den[1],
        "orddenom_axis_units_lab": den[2],
        "z_axis_spec_data_type": 0,
        "x": np.asarray(x, dtype=float), "data": y,
    }
