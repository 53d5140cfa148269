"""UFF units (dataset 164) and node geometry (datasets 2411 and 15).

ssidlab writes SI (units code 1, all factors 1) and node coordinates in dataset 2411 (double
precision). On reading, a dataset 164 gives the factors that convert the file's units to SI
(the standard's rule: *divide* a file value by the factor of its unit), and geometry comes
from 2411 or, in older files, 15.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from ssid.errors import InputError

from ._uffio import read_datasets, write_datasets
from .labels import MAX_NODE

__all__ = [
    "geometry_dataset",
    "read_uff_geometry",
    "si_units_dataset",
    "unit_factors",
    "write_uff_geometry",
]

Geometry = Mapping[int, "tuple[float, float, float] | np.ndarray"]


def si_units_dataset() -> dict:
    """Dataset 164 declaring SI units (metre, newton, kelvin; all conversion factors 1)."""
    return {"type": 164, "units_code": 1, "units_description": "SI", "temp_mode": 1,
            "length": 1.0, "force": 1.0, "temp": 1.0, "temp_offset": 273.15}


def unit_factors(src: str, datasets: list[dict]) -> tuple[float, float]:
    """(length, force) factors of the file's first dataset 164; (1, 1) when it has none.

    A value in file units divided by its factor is in SI, so an FRF in length/force units is
    converted with ``H_si = H_file * force / length``.
    """
    units = [d for d in datasets if d.get("type") == 164]
    if not units:
        return 1.0, 1.0
    d = units[0]
    length, force = float(d.get("length", 0.0)), float(d.get("force", 0.0))
    if not (np.isfinite(length) and np.isfinite(force) and length > 0 and force > 0):
        raise InputError(f"{src}: dataset {d['_index'] + 1} (units, 164) has conversion "
                         f"factors length={length:g}, force={force:g}; both must be > 0")
    for other in units[1:]:
        if (float(other.get("length", 0)), float(other.get("force", 0))) != (length, force):
            raise InputError(f"{src}: datasets {d['_index'] + 1} and {other['_index'] + 1} "
                             "declare different units (164)")
    return length, force


def geometry_dataset(src: str, geometry: Geometry) -> dict:
    """Dataset 2411 for ``{node: (x, y, z)}`` in metres, global coordinate system."""
    nodes = sorted(int(n) for n in geometry)
    if not nodes:
        raise InputError(f"{src}: geometry is empty")
    xyz = np.empty((len(nodes), 3))
    for k, node in enumerate(nodes):
        if not 1 <= node <= MAX_NODE:
            raise InputError(f"{src}: geometry node number {node} is outside 1 .. {MAX_NODE}")
        p = np.asarray(geometry[node], dtype=float).ravel()
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"{src}: geometry of node {node} must be 3 finite coordinates, "
                             f"got {geometry[node]!r}")
        xyz[k] = p
    n = len(nodes)
    # 2411 record 1: node label, export CS, displacement CS, colour (0 = global CS).
    return {"type": 2411, "node_nums": np.array(nodes), "def_cs": np.zeros(n, int),
            "disp_cs": np.zeros(n, int), "color": np.full(n, 11, int),
            "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}


def write_uff_geometry(path: str | os.PathLike, geometry: Geometry) -> None:
    """Write node coordinates (metres) as a UFF file with datasets 164 and 2411."""
    src = os.fspath(path)
    write_datasets(path, [si_units_dataset(), geometry_dataset(src, geometry)])


def geometry_from_datasets(src: str, datasets: list[dict]) -> dict[int, np.ndarray]:
    """Node coordinates in metres from datasets 2411/15 (and 164 units) already read."""
    length, _ = unit_factors(src, datasets)
    out: dict[int, np.ndarray] = {}
    for d in datasets:
        if d.get("type") not in (15, 2411):
            continue
        nodes = np.asarray(d.get("node_nums", []), dtype=float)
        xyz = np.column_stack([np.asarray(d.get(k, []), dtype=float) for k in "xyz"])
        if xyz.shape[0] != nodes.size or not np.all(np.isfinite(xyz)):
            raise InputError(f"{src}: dataset {d['_index'] + 1} (nodes, {d['type']}) is malformed")
        for node, p in zip(nodes, xyz):
            out[int(node)] = p / length
    return out


def read_uff_geometry(path: str | os.PathLike) -> dict[int, np.ndarray]:
    """Node coordinates ``{node: array([x, y, z])}`` in metres from a UFF file.

    Raises
    ------
    InputError
        Unreadable file, or no node dataset (2411 or 15) in it.
    """
    src = os.fspath(path)
    datasets = read_datasets(path, types={15, 164, 2411})
    geometry = geometry_from_datasets(src, datasets)
    if not geometry:
        raise InputError(f"{src}: no node coordinates (dataset 2411 or 15) in the file")
    return geometry
