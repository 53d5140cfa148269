"""The model file (``format = "ssidlab-model"``): the Model object; read, write, validate."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._common import (
    _MODEL_RESERVED_ATTRS,
    FORMAT_VERSION,
    MODEL_FORMAT,
    SYMMETRY_RTOL,
    PathLike,
    _check_kind,
    _create_h5,
    _error,
    _extra_attrs,
    _first,
    _labels,
    _open_h5,
    _read_extra_attrs,
    _read_labels,
    _read_numeric,
    _real,
    _require_finite,
    _write_extra_attrs,
    _write_labels,
)

#: ``units`` attribute of each matrix dataset: SI, generalised (kg m^2, N m/rad, ...) at a
#: rotational DOF.
MATRIX_UNITS = {"M": "kg", "C": "N s/m", "K": "N/m"}


@dataclass
class Model:
    """A structural model in the contract's model-file layout.

    Attributes
    ----------
    M, K : (n, n) float
        Mass (kg) and stiffness (N/m) matrices, symmetric.
    C : (n, n) float or None
        Viscous damping matrix (N s/m); None means undamped.
    dofs : list of str, (n,)
        DOF label of each row and column.
    attrs : dict
        Further root attributes of the file (provenance etc.), written back unchanged.
    """

    M: np.ndarray
    K: np.ndarray
    C: np.ndarray | None
    dofs: list[str]
    attrs: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of DOFs."""
        return len(self.dofs)



# ----------------------------------------------------------------------------------------------
# Model files
# ----------------------------------------------------------------------------------------------


def read_model(path: PathLike) -> Model:
    """Read and validate an ``ssidlab-model`` file.

    Parameters
    ----------
    path : str or path-like
        The HDF5 file.

    Returns
    -------
    Model
        float64 matrices, ``C`` None when the file has no ``/C``, labels as ``str``.

    Raises
    ------
    InputError
        The file is missing, not HDF5, not a model file of a supported version, or its
        content breaks the layout (see :func:`validate_model`).
    """
    src = os.fspath(path)
    with _open_h5(path, src) as f:
        _check_kind(src, f, MODEL_FORMAT)
        raw = Model(
            M=_read_numeric(src, f, "M"),
            K=_read_numeric(src, f, "K"),
            C=_read_numeric(src, f, "C", required=False),
            dofs=_read_labels(src, f, "dofs"),
            attrs=_read_extra_attrs(f, _MODEL_RESERVED_ATTRS),
        )
    return validate_model(raw, src)


def write_model(path: PathLike, model: Model) -> None:
    """Validate ``model`` and write it as an ``ssidlab-model`` file.

    Written under a temporary name and then renamed, like :func:`write_frf`.

    Parameters
    ----------
    path : str or path-like
        Target file; overwritten if it exists.
    model : Model
        The model; ``/C`` is written only when ``model.C`` is not None.

    Raises
    ------
    InputError
        ``model`` would not make a valid file (same checks as :func:`read_model`).
    OSError
        The file cannot be created.
    """
    src = os.fspath(path)
    data = validate_model(model, src)
    with _create_h5(path) as f:
        _write_extra_attrs(src, f, data.attrs, _MODEL_RESERVED_ATTRS)
        f.attrs["format"] = MODEL_FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        # SI (the contract's convention), said in the file too; reading ignores dataset attrs.
        f.create_dataset("M", data=data.M).attrs["units"] = MATRIX_UNITS["M"]
        f.create_dataset("K", data=data.K).attrs["units"] = MATRIX_UNITS["K"]
        if data.C is not None:
            f.create_dataset("C", data=data.C).attrs["units"] = MATRIX_UNITS["C"]
        _write_labels(f, "dofs", data.dofs)


def validate_model(model: Model, source: str = "model") -> Model:
    """Check a :class:`Model` against the model-file layout and return a normalised copy.

    Checks: ``dofs`` are unique strings; ``M``, ``K`` and (if present) ``C`` are real, finite,
    ``(n, n)`` with ``n = len(dofs)``; ``M`` and ``K`` are symmetric to a relative 1e-6 of
    their largest entry (an exporter's rounding), and returned exactly symmetric. ``C`` need
    not be symmetric.

    Parameters
    ----------
    model : Model
        Model to check; not modified.
    source : str
        Name used at the start of error messages (normally the file path).

    Returns
    -------
    Model
        float64 matrices, labels as a list of ``str``, reserved keys dropped from ``attrs``.

    Raises
    ------
    InputError
        The first problem found, as one line starting with ``source``.
    """
    src = source
    dofs = _labels(src, "dofs", model.dofs)
    n = len(dofs)

    def matrix(name: str, value: Any) -> np.ndarray:
        A = _real(src, name, value)
        if A.ndim != 2 or A.shape[0] != A.shape[1]:
            raise _error(src, f"{name} must be a square matrix, got shape {A.shape}")
        if A.shape != (n, n):
            raise _error(src, f"{name} is {A.shape[0]} x {A.shape[1]} but there are {n} dofs")
        _require_finite(
            src, name, A, lambda idx: f"row {dofs[idx[0]]!r}, column {dofs[idx[1]]!r}"
        )
        return A

    M = matrix("M", model.M)
    K = matrix("K", model.K)
    C = None if model.C is None else matrix("C", model.C)
    for name, A in (("M", M), ("K", K)):
        asym = np.abs(A - A.T)
        scale = float(np.abs(A).max())
        if asym.max() > SYMMETRY_RTOL * scale:
            i, j = _first(asym == asym.max())
            raise _error(
                src,
                f"{name} is not symmetric: |{name}[i,j] - {name}[j,i]| = {asym[i, j]:.3g} at "
                f"({dofs[i]!r}, {dofs[j]!r}) exceeds {SYMMETRY_RTOL:g} x max|{name}| "
                f"= {SYMMETRY_RTOL * scale:.3g}",
            )
    M, K = (M + M.T) / 2, (K + K.T) / 2
    attrs = _extra_attrs(src, model.attrs, _MODEL_RESERVED_ATTRS)
    return Model(M=M, K=K, C=C, dofs=dofs, attrs=attrs)


