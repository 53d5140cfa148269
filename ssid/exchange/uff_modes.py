"""Mode shapes as UFF dataset 55 (one dataset per mode), through pyuff.

Complex modes (e.g. an :class:`ssid.result.SSIDResult`) are written as analysis type 3
(complex eigenvalue, first order) with the root ``lambda = -zeta w_n + j w_n sqrt(1 - zeta^2)``
in rad/s; real modes as analysis type 2 (normal mode) with the frequency in Hz and the viscous
damping ratio. Values are per node in global X, Y, Z (and RX, RY, RZ for real modes): a label
``"4-Z"`` stores minus its value in node 4's Z slot, and components without a label are 0.
pyuff reads and writes complex dataset 55 with three values per node only, so complex modes
with rotational DOFs cannot be written. Dataset 55 is ASCII E13.5: 6 significant digits.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ssid.errors import InputError

from ._uffio import read_datasets, write_datasets
from .labels import DIRECTIONS, labels_to_node_dirs
from .uff_geometry import Geometry, geometry_dataset, si_units_dataset

__all__ = [
    "UFFModes",
    "mode_datasets",
    "modes_from_model",
    "modes_from_result",
    "read_uff_modes",
    "write_uff_modes",
]


@dataclass
class UFFModes:
    """Modes read from (or to be written to) a UFF file.

    Attributes
    ----------
    natural_freq_hz, damping_ratio : (m,) float
        Undamped natural frequency ``|lambda| / 2 pi`` and viscous damping ratio of each mode.
    mode_shapes : (n, m) complex (or float for real modes)
        One column per mode.
    dofs : list of str, (n,)
        DOF label of each row.
    mode_numbers : (m,) int, optional
        Number of each mode in its source (dataset 55's mode number, ID line 1 ``Mode k``);
        None: 1 .. m. A result whose undetermined modes are left out keeps the numbers of
        the others (mode 3 of a result whose mode 2 is null stays mode 3).
    """

    natural_freq_hz: np.ndarray
    damping_ratio: np.ndarray
    mode_shapes: np.ndarray
    dofs: list[str]
    mode_numbers: np.ndarray | None = None

    def numbers(self) -> np.ndarray:
        """(m,) int: the modes' numbers, 1 .. m unless :attr:`mode_numbers` says otherwise."""
        m = np.asarray(self.natural_freq_hz).size
        if self.mode_numbers is None:
            return np.arange(1, m + 1)
        return np.asarray(self.mode_numbers, dtype=int).ravel()


# ----------------------------------------------------------------------------------------------
# Sources of modes
# ----------------------------------------------------------------------------------------------


def modes_from_result(result: Any, *, source: str = "result") -> UFFModes:
    """Modes of an :class:`ssid.result.SSIDResult` or of its JSON dictionary.

    Modes whose frequency or damping is undetermined (NaN, or null in JSON) are left out;
    the others keep their numbers in the result (``mode_numbers``).

    Parameters
    ----------
    result : SSIDResult or mapping
        ``natural_freq_hz``, ``damping_ratio``, ``mode_shapes`` (in JSON: ``{"real", "imag",
        "dofs"}``) and ``dofs``.
    source : str
        Names the result (its file) in messages.

    Raises
    ------
    InputError
        Not a result (a JSON array, number or string), missing or non-numeric parts, shapes
        and labels that disagree, a frequency that is not positive, or a zero mode shape.
    """
    if isinstance(result, Mapping):
        shapes = result.get("mode_shapes")
        if not isinstance(shapes, Mapping) or "real" not in shapes or "imag" not in shapes:
            raise InputError(f"{source}: no 'mode_shapes' with 'real' and 'imag' parts")
        try:
            phi = np.asarray(shapes["real"], float) + 1j * np.asarray(shapes["imag"], float)
            f = np.array([np.nan if v is None else v for v in result["natural_freq_hz"]], float)
            z = np.array([np.nan if v is None else v for v in result["damping_ratio"]], float)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: natural_freq_hz, damping_ratio or mode_shapes are not "
                             f"numeric lists ({exc})") from None
        dofs = shapes.get("dofs") or result.get("dofs") or []
    elif all(hasattr(result, name) for name in ("mode_shapes", "natural_freq_hz", "damping_ratio", "dofs")):
        phi = np.asarray(result.mode_shapes)
        f, z = np.asarray(result.natural_freq_hz, float), np.asarray(result.damping_ratio, float)
        dofs = result.dofs
    else:
        # A JSON file that parses but holds an array, a number or a string is not a result.
        raise InputError(f"{source}: not an ssidlab result (expected a JSON object with "
                         f"natural_freq_hz, damping_ratio and mode_shapes, got {_json_kind(result)})")
    if isinstance(dofs, (str, bytes)) or not isinstance(dofs, Sequence) \
            or not all(isinstance(d, str) for d in dofs):
        raise InputError(f"{source}: dofs must be a list of DOF label strings, got {dofs!r:.60}")
    dofs = list(dofs)
    twice = next((d for k, d in enumerate(dofs) if d in dofs[:k]), None)
    if twice is not None:
        raise InputError(f"{source}: duplicate label {twice!r} in dofs")
    phi = np.atleast_2d(phi)
    if phi.ndim != 2 or phi.shape[1] != f.size or z.size != f.size:
        raise InputError(f"{source}: mode_shapes {phi.shape} do not match {f.size} frequencies "
                         f"and {z.size} damping ratios")
    if phi.shape[0] != len(dofs):
        raise InputError(f"{source}: mode_shapes have {phi.shape[0]} rows but dofs lists "
                         f"{len(dofs)} labels")
    labels_to_node_dirs(source, dofs, "dofs", "UFF dataset 55")
    keep = np.isfinite(f) & np.isfinite(z) & np.all(np.isfinite(phi), axis=0)
    modes = UFFModes(f[keep], z[keep], phi[:, keep], dofs, np.flatnonzero(keep) + 1)
    _refuse_bad_modes(source, modes, modes.numbers(), complex_=True)
    return modes


def _json_kind(value: Any) -> str:
    """What a parsed JSON value is, for a message: ``an array``, ``a number`` ..."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    return f"a {type(value).__name__}"


def _refuse_bad_modes(where: str, modes: UFFModes, numbers: Sequence[int] | np.ndarray,
                      *, complex_: bool) -> None:
    """Refuse modes that dataset 55 would hold as garbage, naming ``where`` and the mode.

    A negative frequency is no mode: a complex mode's eigenvalue reads back as ``|lambda|``,
    so the sign would be lost without a word, and a normal mode's is plain garbage. A
    complex mode at 0 Hz has no eigenvalue to write (its damping reads back as NaN); a
    frequency whose ``2 pi f`` overflows is written as Inf; a shape that is zero at every DOF
    is no shape. ``numbers`` are the modes' numbers in the source (1-based).
    """
    f = np.asarray(modes.natural_freq_hz, dtype=float)
    phi = np.atleast_2d(np.asarray(modes.mode_shapes))
    with np.errstate(over="ignore"):
        wn = 2 * np.pi * f
    low = (f <= 0) if complex_ else (f < 0)
    for k in range(f.size):
        if low[k]:
            need = "positive" if complex_ else "at least 0 (rigid-body modes)"
            raise InputError(f"{where}: mode {numbers[k]} has the frequency {f[k]:g} Hz; a mode's "
                             f"natural frequency must be {need}")
        if not np.isfinite(wn[k]):
            raise InputError(f"{where}: mode {numbers[k]} has the frequency {f[k]:g} Hz, too large "
                             "for its eigenvalue in rad/s to be a finite number")
        if phi.shape[0] and not np.any(phi[:, k]):
            raise InputError(f"{where}: the shape of mode {numbers[k]} is zero at every DOF")


def modes_from_model(M: np.ndarray, C: np.ndarray | None, K: np.ndarray,
                     dofs: Sequence[str], *, source: str = "model") -> UFFModes:
    """Complex modes of (M, C, K), or real normal modes of (M, K) when ``C`` is None.

    Complex shapes are scaled so that their largest entry is 1 (as an SSIDResult's). Real
    modes include a free-free model's rigid-body modes, at 0 Hz.

    Parameters
    ----------
    M, C, K : (n, n) arrays; ``C`` None for an undamped model
    dofs : sequence of str, (n,)
    source : str
        Names the model (its file) in messages.

    Raises
    ------
    InputError
        M not positive definite (zero, singular: massless DOFs, or with a negative
        eigenvalue), K not positive semi-definite (an unstable structure), or no mode to write
        (K zero: no elastic mode; every complex root real: overdamped throughout). These are
        refused as ``ssidlab place`` and ``correlate`` refuse them where they compute modes.
    """
    from ssid.modal import complex_modes, root_frequency_damping, unit_max_shapes
    from ssid.tam import normal_modes, require_elastic_modes, require_stable_stiffness

    M, K = np.asarray(M, dtype=float), np.asarray(K, dtype=float)
    labels_to_node_dirs(source, list(dofs), "dofs", "UFF dataset 55")
    _require_mass_matrix(source, M)
    lam, phi_real = normal_modes(M, K)  # M is positive definite: no LinAlgError
    require_stable_stiffness(lam, source)
    require_elastic_modes(K, source, "the modes written to UFF dataset 55")
    if C is None:
        # Round-off on rigid-body modes (within n_unstable_modes' tolerance) is 0 Hz.
        wn = np.sqrt(np.clip(lam, 0.0, None))
        return UFFModes(wn / (2 * np.pi), np.zeros(wn.size), phi_real, list(dofs))
    try:
        roots, phi = complex_modes(M, np.asarray(C, dtype=float), K)
    except np.linalg.LinAlgError as exc:  # pragma: no cover - M was checked above
        raise InputError(f"{source}: cannot compute the model's modes ({exc})") from None
    if roots.size == 0:
        raise InputError(f"{source}: the model has no oscillating mode: every root of (M, C, K) "
                         "is real (rigid-body or overdamped), so dataset 55 has nothing to hold")
    wn, zeta = root_frequency_damping(roots)
    return UFFModes(wn / (2 * np.pi), zeta, unit_max_shapes(phi), list(dofs))


def _require_mass_matrix(source: str, M: np.ndarray) -> None:
    """Refuse an M that is not positive definite, saying how (the modes need ``M^-1``)."""
    try:
        np.linalg.cholesky(M)
        return
    except np.linalg.LinAlgError:
        pass
    ev = np.linalg.eigvalsh((M + M.T) / 2)
    top = float(np.max(np.abs(ev))) if ev.size else 0.0
    if top == 0.0:
        problem = "M is zero"
    elif ev[0] < -1e-12 * top:
        problem = f"M has the negative eigenvalue {ev[0]:.4g}: not the mass matrix of a structure"
    else:
        problem = "M is singular (massless DOFs?); reduce them out first, e.g. by Guyan reduction"
    raise InputError(f"{source}: {problem}; M must be positive definite for the modes written "
                     "to UFF dataset 55")


# ----------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------


def write_uff_modes(path: str | os.PathLike, modes: UFFModes, *, real: bool | None = None,
                    geometry: Geometry | None = None) -> None:
    """Write modes as a UFF file of datasets 164, [2411,] and one 55 per mode.

    Parameters
    ----------
    path : str or path-like
    modes : UFFModes
        Shapes (n, m) over ``dofs`` in node+direction form; scalar points cannot be written.
    real : bool, optional
        Write normal modes (analysis type 2; shapes must be real). Default: real exactly when
        the shapes have no imaginary part.
    geometry : mapping of node -> (x, y, z), optional
        Node coordinates in metres (dataset 2411).

    Raises
    ------
    InputError
        Shapes and labels disagree, non-finite values, |damping ratio| >= 1 for a complex
        mode, scalar or duplicate DOFs, rotational DOFs in complex modes.
    """
    src = os.fspath(path)
    write_datasets(path, mode_datasets(src, modes, real=real, geometry=geometry))


def mode_datasets(src: str, modes: UFFModes, *, real: bool | None = None,
                  geometry: Geometry | None = None) -> list[dict]:
    """The pyuff dataset dictionaries :func:`write_uff_modes` writes."""
    phi = np.atleast_2d(np.asarray(modes.mode_shapes))
    f = np.asarray(modes.natural_freq_hz, dtype=float).ravel()
    zeta = np.asarray(modes.damping_ratio, dtype=float).ravel()
    dofs = list(modes.dofs)
    if phi.shape != (len(dofs), f.size) or zeta.size != f.size or f.size == 0:
        raise InputError(f"{src}: mode shapes {phi.shape} must be (n_dofs, n_modes) = "
                         f"({len(dofs)}, {f.size}) with one damping ratio per mode")
    numbers = modes.numbers()
    if numbers.size != f.size or np.any(numbers < 1) or np.unique(numbers).size != f.size:
        raise InputError(f"{src}: mode numbers {numbers.tolist()} must be {f.size} different "
                         "numbers >= 1")
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(f)) and np.all(np.isfinite(zeta))):
        raise InputError(f"{src}: mode data hold NaN or Inf")
    is_real = not np.iscomplexobj(phi) or not np.any(phi.imag)
    real = is_real if real is None else real
    if real and not is_real:
        raise InputError(f"{src}: real (normal) modes requested but the shapes are complex")
    if not real and np.any(np.abs(zeta) >= 1):
        raise InputError(f"{src}: a complex mode needs |damping ratio| < 1, got "
                         f"{zeta[np.abs(zeta) >= 1][0]:g}")
    _refuse_bad_modes(src, modes, numbers, complex_=not real)
    node_dirs = labels_to_node_dirs(src, dofs, "dofs", "UFF dataset 55")
    nodes, slots = _node_slots(src, dofs, node_dirs, allow_rotations=real)
    n_per_node = 6 if any(abs(d) > 3 for _, d in node_dirs) else 3
    stamp = time.strftime("%d-%b-%y %H:%M:%S")
    out: list[dict] = [si_units_dataset()]
    if geometry:
        out.append(geometry_dataset(src, geometry))
    for k in range(f.size):
        values = np.zeros((len(nodes), n_per_node), dtype=float if real else complex)
        for row, (i, c, sign) in enumerate(slots):
            values[i, c] = sign * (phi[row, k].real if real else phi[row, k])
        d: dict[str, Any] = {
            "type": 55, "id1": f"Mode {numbers[k]}", "id2": "ssidlab", "id3": stamp,
            "id4": "NONE", "id5": "NONE", "model_type": 1,
            "data_ch": 3 if n_per_node == 6 else 2, "spec_data_type": 8,
            "load_case": 1, "mode_n": int(numbers[k]), "node_nums": np.array(nodes),
        }
        if real:
            d.update(analysis_type=2, freq=float(f[k]), modal_m=0.0,
                     modal_damp_vis=float(zeta[k]), modal_damp_his=0.0)
        else:
            wn = 2 * np.pi * f[k]
            d.update(analysis_type=3, modal_a=0j, modal_b=0j,
                     eig=complex(-zeta[k] * wn, wn * np.sqrt(1 - zeta[k] ** 2)))
        for c in range(n_per_node):
            d[f"r{c + 1}"] = values[:, c]
        out.append(d)
    return out


def _node_slots(src: str, dofs: list[str], node_dirs: list[tuple[int, int]],
                allow_rotations: bool) -> tuple[list[int], list[tuple[int, int, float]]]:
    """Nodes in order of appearance and, per label, (node index, component, sign)."""
    nodes: dict[int, int] = {}
    used: dict[tuple[int, int], str] = {}
    slots = []
    for label, (node, direction) in zip(dofs, node_dirs):
        if direction == 0:
            raise InputError(f"{src}: DOF {label!r} is a scalar point; dataset 55 holds "
                             "vectors per node")
        if abs(direction) > 3 and not allow_rotations:
            raise InputError(f"{src}: DOF {label!r} is a rotation; complex modes in dataset "
                             "55 carry 3 translations per node (pyuff), write real modes or "
                             "leave rotations out")
        c = abs(direction) - 1
        if (node, c) in used:
            raise InputError(f"{src}: DOFs {used[(node, c)]!r} and {label!r} are the same "
                             "node component")
        used[(node, c)] = label
        i = nodes.setdefault(node, len(nodes))
        slots.append((i, c, 1.0 if direction > 0 else -1.0))
    return list(nodes), slots


# ----------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------


def read_uff_modes(path: str | os.PathLike, dofs: Sequence[str] | None = None) -> UFFModes:
    """Read the modes (datasets 55, analysis types 2, 3, 7) of a UFF file.

    Parameters
    ----------
    path : str or path-like
    dofs : sequence of str, optional
        Labels to return, in this order (``"4-Z"`` gives minus node 4's Z value). Default:
        every component of every node, ``"<node>+X"`` ... (``+RZ`` for 6 values per node).

    Returns
    -------
    UFFModes
        In file order, with the file's mode numbers; frequency and damping from the complex root (``|lambda|/2pi``,
        ``-Re(lambda)/|lambda|``, lambda in rad/s) or, for normal modes, as stored.

    Raises
    ------
    InputError
        Unreadable file, no modes, a requested DOF that the file does not hold.
    """
    src = os.fspath(path)
    datasets = [d for d in read_datasets(path, types={55}) if d.get("analysis_type") in (2, 3, 7)]
    if not datasets:
        raise InputError(f"{src}: no mode shapes (dataset 55 of a normal or complex mode "
                         "analysis) in the file")
    freq, zeta, columns = [], [], []
    n_comp = 3
    for d in datasets:
        if d["analysis_type"] == 2:
            freq.append(float(d.get("freq", np.nan)))
            zeta.append(float(d.get("modal_damp_vis", 0.0)))
        else:
            lam = complex(d.get("eig", np.nan))
            wn = abs(lam)
            freq.append(wn / (2 * np.pi))
            zeta.append(-lam.real / wn if wn > 0 else np.nan)
        nodes = np.asarray(d.get("node_nums", []), dtype=int)
        comps = [np.asarray(d[f"r{c}"]) for c in range(1, 7) if f"r{c}" in d]
        n_comp = max(n_comp, len(comps))
        if not comps or any(v.shape != nodes.shape for v in comps):
            raise InputError(f"{src}: dataset {d['_index'] + 1} (55) is malformed")
        columns.append({(int(n), c): v[i] for c, v in enumerate(comps)
                        for i, n in enumerate(nodes)})
    all_nodes = list(dict.fromkeys(n for col in columns for n, _ in col))
    if dofs is None:
        dofs = [f"{n}+{DIRECTIONS[c]}" for n in all_nodes for c in range(n_comp)]
    node_dirs = labels_to_node_dirs(src, list(dofs), "dofs", "UFF dataset 55")
    phi = np.zeros((len(dofs), len(columns)), dtype=complex)
    for row, (label, (node, direction)) in enumerate(zip(dofs, node_dirs)):
        key = (node, abs(direction) - 1)
        if direction == 0 or not any(key in col for col in columns):
            raise InputError(f"{src}: the modes hold no value for DOF {label!r}")
        sign = 1.0 if direction > 0 else -1.0
        phi[row] = [sign * col.get(key, 0.0) for col in columns]
    if all(d["analysis_type"] == 2 for d in datasets):
        phi = phi.real
    # The modes' numbers as the file gives them, when they can be (distinct, >= 1).
    numbers = [d.get("mode_n") for d in datasets]
    known = all(isinstance(n, (int, np.integer)) and n >= 1 for n in numbers)
    mode_numbers = np.array(numbers, dtype=int) if known and len(set(numbers)) == len(numbers) else None
    return UFFModes(np.array(freq), np.array(zeta), phi, list(dofs), mode_numbers)
