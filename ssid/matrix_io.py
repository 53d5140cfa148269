"""Read analysis M, K (and C) from where users have them: our model file, MATLAB, Nastran OP4.

:func:`read_analysis_model` picks the reader from the file's content (and, for OP4, which
has no signature, its extension):

* ``ssidlab-model`` HDF5 files (:func:`ssid.io.read_model`);
* MATLAB ``.mat`` files, versions 4-7 through :func:`scipy.io.loadmat` and version 7.3 (HDF5)
  through h5py, including sparse matrices and cell arrays of strings;
* Nastran ``.op4`` files (ASCII or binary, dense or sparse) through pyyeti's maintained
  ``pyyeti.nastran.op4`` reader, imported only when needed.

Matrices are found by name, case-insensitive: mass ``M, MAA, MGG, MFF, MLL, MASS``; stiffness
``K, KAA, KGG, KFF, KLL, STIFFNESS``; damping (optional) ``C, BAA, BGG, BFF, BLL, DAMPING``.
DOF labels come from a variable ``dofs`` (or ``labels``): strings, or Nastran's ``(n, 2)``
``[grid, component]`` pairs, written ``"<grid>+<X|Y|Z|RX|RY|RZ>"`` (component 0, a scalar
point, is ``"<grid>"``). Every problem raises :class:`ssid.errors.InputError` with one line
``"<file>: <problem>"``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import InputError
from .io import Model, read_model, validate_model

__all__ = [
    "DAMPING_NAMES",
    "LABEL_NAMES",
    "MASS_NAMES",
    "STIFFNESS_NAMES",
    "labels_from_grid_components",
    "read_analysis_model",
]

MASS_NAMES = ("m", "maa", "mgg", "mff", "mll", "mass")
STIFFNESS_NAMES = ("k", "kaa", "kgg", "kff", "kll", "stiffness")
DAMPING_NAMES = ("c", "baa", "bgg", "bff", "bll", "damping")
LABEL_NAMES = ("dofs", "labels")

_COMPONENTS = {0: "", 1: "+X", 2: "+Y", 3: "+Z", 4: "+RX", 5: "+RY", 6: "+RZ"}


def _err(src: str, problem: str) -> InputError:
    return InputError(" ".join(f"{src}: {problem}".splitlines()))


def read_analysis_model(
    path: str | os.PathLike,
    *,
    dofs: Sequence[str] | None = None,
    mass: str | None = None,
    stiffness: str | None = None,
    damping: str | None = None,
) -> Model:
    """Read an analysis model (M, K, optional C and DOF labels) from a model, MAT or OP4 file.

    Parameters
    ----------
    path : str or path-like
    dofs : sequence of str, optional
        DOF labels, overriding (or supplying, for files without) the file's ``dofs``.
    mass, stiffness, damping : str, optional
        Variable names to use instead of the default lists (MAT and OP4 only).

    Returns
    -------
    Model
        Validated (square, finite, symmetric M and K, unique labels).

    Raises
    ------
    InputError
        Missing or unreadable file, unknown format, missing or ambiguous matrices, no labels.
    """
    src = os.fspath(path)
    if not os.path.exists(src):
        raise _err(src, "no such file")
    if not os.path.isfile(src):
        raise _err(src, "not a file")
    try:
        with open(src, "rb") as f:
            head = f.read(128)
    except OSError as exc:
        raise _err(src, f"cannot read the file ({exc.strerror or exc})") from None
    if head.startswith(b"MATLAB 7.3"):
        variables = _read_mat73(src)
    elif head.startswith(b"\x89HDF\r\n\x1a\n"):
        model = read_model(src)
        if dofs is not None:
            model = validate_model(Model(model.M, model.K, model.C, list(dofs), model.attrs), src)
        return model
    elif head.startswith(b"MATLAB") or src.lower().endswith(".mat"):
        variables = _read_mat(src)
    elif src.lower().endswith(".op4"):
        variables = _read_op4(src)
    else:
        raise _err(src, "not a recognised matrix file (expected an ssidlab-model .h5, a MATLAB "
                        ".mat or a Nastran .op4 file)")
    return _model_from_variables(src, variables, dofs, mass, stiffness, damping)


# ----------------------------------------------------------------------------------------------
# Readers: each returns {lower-case name: ndarray or list of str}
# ----------------------------------------------------------------------------------------------


def _read_mat(src: str) -> dict[str, Any]:
    import scipy.io

    try:
        raw = scipy.io.loadmat(src, squeeze_me=False, chars_as_strings=True)
    except NotImplementedError:  # v7.3 without our header check (should not happen)
        return _read_mat73(src)
    except Exception as exc:  # noqa: BLE001 -- scipy raises many types on damaged files
        raise _err(src, f"not a readable MATLAB .mat file ({type(exc).__name__}: {exc})") from None
    out: dict[str, Any] = {}
    for name, value in raw.items():
        if name.startswith("__"):
            continue
        out[name.lower()] = _mat_value(value)
    return out


def _mat_value(value: Any) -> Any:
    """A loadmat value as a dense float array or a list of strings."""
    if hasattr(value, "toarray"):  # scipy sparse
        return np.asarray(value.toarray())
    a = np.asarray(value)
    if a.dtype.kind == "U":  # char matrix: one padded row per label
        return [str(s).strip() for s in a.ravel()]
    if a.dtype == object:  # cell array
        items = []
        for cell in a.ravel(order="F"):
            c = np.asarray(cell)
            if c.dtype.kind != "U":
                return a  # not a cell array of strings: left for the caller to refuse
            items.append(str(c.ravel()[0]).strip() if c.size else "")
        return items
    return a


def _read_mat73(src: str) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    try:
        with h5py.File(src, "r") as f:
            for name in f:
                if name.startswith("#"):
                    continue
                # MATLAB writes no links: a soft or external link that leads nowhere (or to a
                # file that is not there) is damage, and h5py gives None for it, not an error.
                obj = f.get(name)
                if obj is None:
                    raise _Damaged(_broken_link(f, name))
                out[name.lower()] = _mat73_value(f, obj, name)
    except (_Damaged, OSError) as exc:
        raise _err(src, f"damaged MATLAB v7.3 file ({exc})") from None
    except (KeyError, ValueError, TypeError, IndexError, RuntimeError) as exc:
        # h5py reports damage inside a file (a bad chunk, a dangling object reference, a
        # sparse matrix whose index arrays disagree) with any of these.
        raise _err(src, f"damaged MATLAB v7.3 file ({type(exc).__name__}: {exc})") from None
    return out


class _Damaged(Exception):
    """A MATLAB v7.3 file whose HDF5 structure is damaged; the message says where."""


def _broken_link(f: Any, name: str) -> str:
    """What the link ``name`` that h5py cannot follow is, for the message."""
    import h5py

    link = f.get(name, getlink=True)
    if isinstance(link, h5py.SoftLink):
        return f"variable {name!r} is a soft link to {link.path!r}, which does not exist"
    if isinstance(link, h5py.ExternalLink):
        return (f"variable {name!r} is an external link to {link.path!r} in {link.filename!r}, "
                "which cannot be opened")
    return f"variable {name!r} cannot be opened"


def _mat73_value(f: Any, obj: Any, name: str) -> Any:
    import h5py
    import scipy.sparse

    cls = obj.attrs.get("MATLAB_class", b"")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
    if isinstance(obj, h5py.Group):
        if "MATLAB_sparse" in obj.attrs and {"data", "ir", "jc"} <= set(obj):
            jc = obj["jc"][()]
            A = scipy.sparse.csc_matrix(
                (obj["data"][()], obj["ir"][()], jc), shape=(int(obj.attrs["MATLAB_sparse"]), jc.size - 1)
            )
            return A.toarray()
        return None
    data = obj[()]
    if cls == "char":  # uint16 codes, MATLAB column-major: one label per column after .T
        codes = np.atleast_2d(np.asarray(data)).T
        return ["".join(chr(c) for c in row if c).strip() for row in codes]
    if cls == "cell":
        items = []
        for k, ref in enumerate(np.asarray(data).T.ravel()):
            # A cell holds object references; a null one (never set) or one to an object
            # that is gone cannot be followed (h5py: "Invalid HDF5 object reference").
            if not isinstance(ref, h5py.Reference):
                raise _Damaged(f"{name!r} is marked a cell array but holds no object references")
            if not ref:
                raise _Damaged(f"cell {k + 1} of {name!r} holds a null reference")
            try:
                target = f[ref]
            except (KeyError, ValueError) as exc:
                raise _Damaged(f"cell {k + 1} of {name!r} refers to no object ({exc})") from None
            v = _mat73_value(f, target, name)
            if not (isinstance(v, list) and len(v) == 1):
                return np.asarray(data)
            items.append(v[0])
        return items
    # MATLAB stores column-major; h5py sees the transpose.
    return np.asarray(data).T


def _read_op4(src: str) -> dict[str, Any]:
    try:
        from pyyeti.nastran import op4
    except ImportError:
        raise _err(src, "reading Nastran OP4 files needs pyyeti (pip install 'pyyeti>=1.4,<2')") from None
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pyyeti warns about renamed garbage matrices
            raw = op4.read(src, sparse=False)
    except MemoryError:
        raise _err(src, "not a readable OP4 file (its header asks for an impossible size)") from None
    except Exception as exc:  # noqa: BLE001 -- ValueError, IndexError, struct.error, ...
        raise _err(src, f"not a readable OP4 file ({type(exc).__name__}: {exc})") from None
    if not raw:
        raise _err(src, "no matrices found in the OP4 file")
    return {str(k).lower(): np.asarray(v) for k, v in raw.items()}


# ----------------------------------------------------------------------------------------------
# From variables to a Model
# ----------------------------------------------------------------------------------------------


def labels_from_grid_components(pairs: np.ndarray) -> list[str]:
    """Nastran ``[grid, component]`` rows (n, 2) as labels ``"4+Z"``, ``"17+RX"``, ``"9"``."""
    a = np.asarray(pairs)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"grid/component pairs must be (n, 2), got shape {a.shape}")
    if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
        raise ValueError("grid/component pairs must be whole numbers")
    out = []
    for grid, comp in a.astype(int):
        if grid < 1:  # Nastran grid IDs run from 1; "-1+Z" would be refused by every export later
            raise ValueError(f"grid {int(grid)} is not a Nastran grid ID (1 or more)")
        if int(comp) not in _COMPONENTS:
            raise ValueError(f"component {int(comp)} of grid {int(grid)} is not 0-6")
        out.append(f"{int(grid)}{_COMPONENTS[int(comp)]}")
    return out


def _pick(src: str, variables: dict[str, Any], names: Sequence[str], what: str,
          explicit: str | None, required: bool) -> Any:
    if explicit is not None:
        key = explicit.lower()
        if key not in variables:
            raise _err(src, f"no variable {explicit!r} ({what}); the file has {_listing(variables)}")
        return variables[key]
    found = [n for n in names if n in variables]
    if len(found) > 1:
        raise _err(src, f"several {what} matrices ({', '.join(found)}): name the one to use")
    if not found:
        if required:
            raise _err(src, f"no {what} matrix (looked for {', '.join(n.upper() for n in names)}); "
                            f"the file has {_listing(variables)}")
        return None
    return variables[found[0]]


def _listing(variables: dict[str, Any]) -> str:
    names = sorted(variables)
    return ", ".join(names[:12]) + (" ..." if len(names) > 12 else "") if names else "no variables"


def _matrix(src: str, name: str, value: Any) -> np.ndarray:
    if isinstance(value, list) or value is None:
        raise _err(src, f"{name} must be a numeric matrix")
    a = np.asarray(value)
    if a.dtype.kind == "c":
        if np.any(a.imag != 0):
            raise _err(src, f"{name} is complex; analysis M, C, K must be real")
        a = a.real
    if a.dtype.kind not in "fiub":
        raise _err(src, f"{name} must be numeric, got {a.dtype}")
    return a.astype(float)


def _labels(src: str, value: Any, n: int) -> list[str]:
    if isinstance(value, list):
        return value
    a = np.asarray(value)
    if a.dtype.kind in "fiu":
        vector = a.ndim <= 1 or min(a.shape) == 1
        if a.ndim == 2 and a.shape == (n, 2):
            pairs = a  # [grid, component] rows, Nastran's usual layout
        elif a.ndim == 2 and a.shape == (2, n):
            pairs = a.T  # the same stored as two rows
        elif vector and a.size == n:
            pairs = None
        elif a.ndim == 2 and a.shape[1] == 2:
            pairs = a  # pairs for a different number of DOFs: validation names the mismatch
        else:
            pairs = None
        if pairs is not None:
            try:
                return labels_from_grid_components(pairs)
            except ValueError as exc:
                raise _err(src, f"dofs: {exc}") from None
        if vector and np.all(a == np.round(a)):
            return [str(int(v)) for v in a.ravel()]
    raise _err(src, "dofs must be strings or (n, 2) [grid, component] pairs, "
                    f"got an array of shape {a.shape}")


def _model_from_variables(src: str, variables: dict[str, Any], dofs: Sequence[str] | None,
                          mass: str | None, stiffness: str | None, damping: str | None) -> Model:
    M = _matrix(src, "M", _pick(src, variables, MASS_NAMES, "mass", mass, True))
    K = _matrix(src, "K", _pick(src, variables, STIFFNESS_NAMES, "stiffness", stiffness, True))
    c_raw = _pick(src, variables, DAMPING_NAMES, "damping", damping, False)
    C = None if c_raw is None else _matrix(src, "C", c_raw)
    if dofs is None:
        raw = next((variables[n] for n in LABEL_NAMES if n in variables), None)
        if raw is None:
            raise _err(src, "no DOF labels: add a variable 'dofs' (strings, or [grid, component] "
                            "rows) or give the labels explicitly")
        labels = _labels(src, raw, M.shape[0] if M.ndim == 2 else -1)
    else:
        labels = list(dofs)
    # An empty cell or a blank row of a char matrix reads as "": a DOF without a label, not a
    # label. The shared validation (ssid.io) takes any string, so it is refused here.
    empty = next((k for k, label in enumerate(labels) if isinstance(label, str) and not label.strip()), None)
    if empty is not None:
        raise _err(src, f"dofs: label {empty + 1} of {len(labels)} is empty (an empty cell or a "
                        "blank row?); every DOF needs a label")
    return validate_model(Model(M=M, K=K, C=C, dofs=labels), src)
