"""Export M, C, K models (identified or analytical) to MATLAB, Nastran OP4 and Nastran DMIG.

* ``.mat`` -- :func:`export_model_mat`: MATLAB v5 file with ``M``, ``K``, ``C`` (only when the
  model is damped) and ``dofs`` as a cell array of strings; any labels.
* ``.op4`` -- :func:`export_model_op4`: Nastran OUTPUT4 through pyyeti (the optional extra
  ``op4``), binary by default; matrices ``MAA``, ``BAA``, ``KAA`` and ``DOFS``, an (n, 2)
  ``[grid, component]`` matrix. Labels must be node+direction.
* ``.dmig`` / ``.bdf`` -- :func:`export_model_dmig`: DMIG bulk data
  (:mod:`ssid.exchange.dmig`), matrices ``MSSID``, ``BSSID``, ``KSSID``.

All three are read back by :func:`ssid.matrix_io.read_analysis_model` (MAT and OP4; DMIG is
a Nastran input). For OP4 and DMIG a label ``"4-Z"`` is grid 4, component 3 with its rows and
columns negated, since the Nastran formats have no reversed axes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .errors import InputError
from .exchange.dmig import NASTRAN_NAME, grid_components, write_dmig
from .files import written_atomically
from .io import SYMMETRY_RTOL, Model, validate_model

__all__ = [
    "DMIG_NAMES",
    "EXPORT_FORMATS",
    "OP4_NAMES",
    "export_model",
    "export_model_dmig",
    "export_model_mat",
    "export_model_op4",
    "format_from_path",
]

#: Default matrix names (mass, damping, stiffness). DMIG names avoid Nastran's own data blocks.
DMIG_NAMES = ("MSSID", "BSSID", "KSSID")
OP4_NAMES = ("MAA", "BAA", "KAA")
EXPORT_FORMATS = {".mat": "mat", ".op4": "op4", ".dmig": "dmig", ".bdf": "dmig", ".dat": "dmig",
                  ".blk": "dmig", ".pch": "dmig"}


def format_from_path(path: str | os.PathLike) -> str:
    """Export format (``"mat"``, ``"op4"``, ``"dmig"``) from the file extension."""
    ext = Path(path).suffix.lower()
    if ext not in EXPORT_FORMATS:
        raise InputError(f"{os.fspath(path)}: cannot tell the export format from the extension "
                         f"{ext!r} (use {', '.join(sorted(EXPORT_FORMATS))})")
    return EXPORT_FORMATS[ext]


def export_model(path: str | os.PathLike, model: Model, fmt: str | None = None, *,
                 names: Sequence[str] | None = None, binary: bool = True) -> str:
    """Export ``model`` in format ``fmt`` (default: from the extension); returns the format.

    ``names`` (mass, damping, stiffness) apply to OP4 and DMIG, ``binary`` to OP4.
    """
    fmt = fmt or format_from_path(path)
    if fmt == "mat":
        export_model_mat(path, model)
    elif fmt == "op4":
        export_model_op4(path, model, binary=binary, names=names or OP4_NAMES)
    elif fmt == "dmig":
        export_model_dmig(path, model, names=names or DMIG_NAMES)
    else:
        raise InputError(f"unknown export format {fmt!r} (mat, op4, dmig)")
    return fmt


def export_model_mat(path: str | os.PathLike, model: Model) -> None:
    """Write ``M``, ``K``, ``C`` (if damped) and ``dofs`` (cellstr) as a MATLAB v5 .mat file.

    Raises
    ------
    InputError
        The model breaks the model-file rules (:func:`ssid.io.validate_model`).
    """
    import scipy.io

    src = os.fspath(path)
    m = validate_model(model, src)
    variables = {"M": m.M, "K": m.K, "dofs": np.array(m.dofs, dtype=object).reshape(-1, 1)}
    if m.C is not None:
        variables["C"] = m.C
    # The file opened here: savemat reports a file it cannot open without naming it.
    with written_atomically(path) as tmp, open(tmp, "wb") as out:
        scipy.io.savemat(out, variables, do_compression=True, oned_as="column")


def _names(src: str, names: Sequence[str]) -> tuple[str, str, str]:
    names = tuple(str(n).upper() for n in names)
    if len(names) != 3 or len(set(names)) != 3:
        raise InputError(f"{src}: give three different matrix names (mass, damping, stiffness), "
                         f"got {list(names)}")
    for name in names:
        if not NASTRAN_NAME.fullmatch(name):
            raise InputError(f"{src}: {name!r} is not a Nastran matrix name (a letter and up "
                             "to 7 letters or digits)")
    return names  # type: ignore[return-value]


def export_model_op4(path: str | os.PathLike, model: Model, *, binary: bool = True,
                     names: Sequence[str] = OP4_NAMES) -> None:
    """Write the model as a Nastran OP4 file with pyyeti: mass, damping (if any), stiffness, DOFS.

    Parameters
    ----------
    path : str or path-like
    model : Model
        DOF labels in node+direction form.
    binary : bool
        Binary OP4 (native float64) or ASCII (1P,E23.16: 17 significant digits); both exact.
    names : (mass, damping, stiffness)
        OP4 matrix names; ``DOFS`` holds ``[grid, component]`` rows.

    Raises
    ------
    InputError
        Invalid model, labels without node+direction form, pyyeti missing, bad names.
    """
    src = os.fspath(path)
    m = validate_model(model, src)
    mass, damping, stiffness = _names(src, names)
    pairs, signs = grid_components(src, m.dofs, "Nastran OP4")
    try:
        from pyyeti.nastran import op4
    except ImportError:
        raise InputError(f"{src}: writing OP4 needs pyyeti (pip install 'ssidlab[op4]')") from None
    flip = signs[:, None] * signs[None, :]
    matrices = {mass: m.M * flip}
    if m.C is not None:
        matrices[damping] = m.C * flip
    matrices[stiffness] = m.K * flip
    matrices["DOFS"] = pairs.astype(float)
    with written_atomically(path) as tmp:
        op4.write(str(tmp), matrices, binary=binary, digits=16)


def export_model_dmig(path: str | os.PathLike, model: Model, *,
                      names: Sequence[str] = DMIG_NAMES) -> None:
    """Write the model as Nastran DMIG bulk data (format: :mod:`ssid.exchange.dmig`).

    M and K are symmetric DMIGs (IFO 6); C is symmetric when it is within the model file's
    symmetry tolerance, otherwise square (IFO 1).

    Raises
    ------
    InputError
        Invalid model, labels without node+direction form, bad names.
    """
    src = os.fspath(path)
    m = validate_model(model, src)
    mass, damping, stiffness = _names(src, names)
    matrices = [(mass, m.M, True)]
    notes = [f"case control: M2GG = {mass}, K2GG = {stiffness}"]
    if m.C is not None:
        scale = float(np.abs(m.C).max()) or 1.0
        symmetric = float(np.abs(m.C - m.C.T).max()) <= SYMMETRY_RTOL * scale
        matrices.append((damping, m.C, symmetric))
        notes = [f"case control: M2GG = {mass}, B2GG = {damping}, K2GG = {stiffness}"]
    matrices.append((stiffness, m.K, True))
    write_dmig(path, matrices, m.dofs, notes)
