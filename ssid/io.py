"""Read and write the ssidlab HDF5 files: measured FRFs and M, C, K models.

The two layouts (``format = "ssidlab-frf"`` and ``"ssidlab-model"``) are fixed by the interface
contract and described in ``docs/formats.md``. Files are small, so whole datasets are read
into numpy arrays and the files are closed again at once.

Every problem found in a file raises :class:`ssid.errors.InputError` with a one-line message
``"<file>: <problem>"``; the command line prints it and exits with status 2. The writers run
the same checks before they write, so we never produce a file that we would refuse to read.
DOF labels are treated as opaque strings: they are compared, never parsed.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ssid.errors import InputError
from ssid.frf import FRFData

__all__ = [
    "FRF_FORMAT",
    "MODEL_FORMAT",
    "FORMAT_VERSION",
    "QUANTITY",
    "Model",
    "read_frf",
    "write_frf",
    "validate_frf",
    "read_model",
    "write_model",
    "validate_model",
]

PathLike = str | os.PathLike

FRF_FORMAT = "ssidlab-frf"
MODEL_FORMAT = "ssidlab-model"
FORMAT_VERSION = 1
QUANTITY = "accelerance"

# M and K come from FE codes or from our own identification; both are symmetric up to
# round-off, so anything beyond this relative level is a wrong file, not numerics.
SYMMETRY_RTOL = 1e-8
# Coherence estimates |Gxy|^2 / (Gxx Gyy) can land a few ulp outside [0, 1]; such values are
# accepted and clipped rather than making a whole measurement unreadable.
COHERENCE_SLACK = 1e-9

# Root attributes that the layouts themselves define; FRFData.attrs / Model.attrs never
# override them on write and never contain them after a read.
_FRF_RESERVED_ATTRS = frozenset({"format", "format_version", "quantity", "n_avg"})
_MODEL_RESERVED_ATTRS = frozenset({"format", "format_version"})


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
# FRF files
# ----------------------------------------------------------------------------------------------


def read_frf(path: PathLike) -> FRFData:
    """Read and validate an ``ssidlab-frf`` file.

    Parameters
    ----------
    path : str or path-like
        The HDF5 file.

    Returns
    -------
    FRFData
        ``freq_hz`` float64, ``H`` / ``H_reaction`` complex128, ``coherence`` / ``H_var``
        float64, ``valid`` bool, labels as lists of ``str``; absent optional items are None.
        Root attributes other than the layout's own are returned in ``attrs``.

    Raises
    ------
    InputError
        The file is missing, not HDF5, not an FRF file of a supported version, or its content
        breaks the layout (see :func:`validate_frf`).
    """
    src = os.fspath(path)
    with _open_h5(path, src) as f:
        _check_kind(src, f, FRF_FORMAT)
        quantity = _attr_str(src, f, "quantity")
        if quantity is None:
            raise _error(src, f"root attribute 'quantity' is missing (expected {QUANTITY!r})")
        if quantity != QUANTITY:
            raise _error(
                src, f"quantity is {quantity!r}; only {QUANTITY!r} ((m/s^2)/N) is supported"
            )
        has_reactions = "reactions" in f
        raw = FRFData(
            freq_hz=_read_numeric(src, f, "freq_hz"),
            H=_read_numeric(src, f, "H"),
            outputs=_read_labels(src, f, "outputs"),
            inputs=_read_labels(src, f, "inputs"),
            coherence=_read_numeric(src, f, "coherence", required=False),
            valid=_read_numeric(src, f, "valid", required=False),
            H_reaction=_read_numeric(src, f, "H_reaction", required=False),
            reactions=_read_labels(src, f, "reactions") if has_reactions else None,
            H_var=_read_numeric(src, f, "H_var", required=False),
            n_avg=_plain(f.attrs["n_avg"]) if "n_avg" in f.attrs else None,
            attrs=_read_extra_attrs(f, _FRF_RESERVED_ATTRS),
        )
    return validate_frf(raw, src)


def write_frf(path: PathLike, frf: FRFData) -> None:
    """Validate ``frf`` and write it as an ``ssidlab-frf`` file.

    The file is written under a temporary name and then renamed, so an existing file at
    ``path`` is either replaced completely or left untouched.

    Parameters
    ----------
    path : str or path-like
        Target file; overwritten if it exists.
    frf : FRFData
        The data. Entries of ``frf.attrs`` become root attributes, except the layout's own
        (``format``, ``format_version``, ``quantity``, ``n_avg``), which are ignored there.

    Raises
    ------
    InputError
        ``frf`` would not make a valid file (same checks as :func:`read_frf`), or an entry of
        ``frf.attrs`` cannot be stored as an HDF5 attribute.
    OSError
        The file cannot be created.
    """
    src = os.fspath(path)
    data = validate_frf(frf, src)
    with _create_h5(path, src) as f:
        _write_extra_attrs(src, f, data.attrs, _FRF_RESERVED_ATTRS)
        f.attrs["format"] = FRF_FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["quantity"] = QUANTITY
        if data.n_avg is not None:
            f.attrs["n_avg"] = data.n_avg
        f.create_dataset("freq_hz", data=data.freq_hz)
        f.create_dataset("H", data=data.H)
        _write_labels(f, "outputs", data.outputs)
        _write_labels(f, "inputs", data.inputs)
        for name in ("coherence", "valid", "H_var", "H_reaction"):
            value = getattr(data, name)
            if value is not None:
                f.create_dataset(name, data=value)
        if data.reactions is not None:
            _write_labels(f, "reactions", data.reactions)


def validate_frf(frf: FRFData, source: str = "FRF data") -> FRFData:
    """Check an :class:`FRFData` against the FRF-file layout and return a normalised copy.

    Checks: labels are unique strings, every input and reaction label is an output label;
    ``freq_hz`` is 1-D, finite, > 0 and strictly increasing; ``H`` is complex with shape
    ``(n_freq, n_out, n_in)``; ``coherence``, ``valid`` and ``H_var`` have the shape of ``H``;
    ``H_reaction`` is complex ``(n_freq, n_react, n_in)`` and comes with ``reactions``; no NaN
    or Inf anywhere, except NaN in ``H`` where ``valid`` is False (blanked values);
    ``0 <= coherence <= 1``; ``H_var >= 0``; ``n_avg`` is a whole number >= 1.

    Parameters
    ----------
    frf : FRFData
        Data to check; not modified.
    source : str
        Name used at the start of error messages (normally the file path).

    Returns
    -------
    FRFData
        Arrays as float64 / complex128 / bool, labels as lists of ``str``, coherence clipped to
        [0, 1], ``n_avg`` as int, reserved keys dropped from ``attrs``.

    Raises
    ------
    InputError
        The first problem found, as one line starting with ``source``.
    """
    src = source
    outputs = _labels(src, "outputs", frf.outputs)
    inputs = _labels(src, "inputs", frf.inputs)
    _require_subset(src, "inputs", inputs, outputs)

    freq = _real(src, "freq_hz", frf.freq_hz)
    if freq.ndim != 1 or freq.size == 0:
        raise _error(src, f"freq_hz must be a non-empty 1-D array, got shape {freq.shape}")
    _require_finite(src, "freq_hz", freq, lambda idx: f"line {idx[0]}")
    if (freq <= 0).any():
        k = int(np.argmax(freq <= 0))
        raise _error(src, f"freq_hz must be > 0, line {k} is {freq[k]:g} Hz")
    step = np.diff(freq)
    if (step <= 0).any():
        k = int(np.argmax(step <= 0))
        raise _error(
            src,
            f"freq_hz must be strictly increasing: line {k + 1} ({freq[k + 1]:g} Hz) "
            f"follows line {k} ({freq[k]:g} Hz)",
        )

    def at(rows: list[str], row_kind: str):
        # Turns an index into (line, row, input) into words a test engineer can look up.
        return lambda idx: (
            f"{freq[idx[0]]:g} Hz (line {idx[0]}), {row_kind} {rows[idx[1]]!r}, "
            f"input {inputs[idx[2]]!r}"
        )

    at_output = at(outputs, "output")
    shape = (freq.size, len(outputs), len(inputs))
    origin = "(n_freq, n_out, n_in) from freq_hz, outputs, inputs"

    H = _complex(src, "H", frf.H)
    _require_shape(src, "H", H, shape, origin)

    valid = None
    if frf.valid is not None:
        valid = _boolean(src, "valid", frf.valid)
        _require_shape(src, "valid", valid, shape, origin)
    # A blanked value carries no information, so acquisition may leave NaN there.
    _require_finite(
        src,
        "H",
        H,
        at_output,
        nan_ok=None if valid is None else ~valid,
        hint="NaN is allowed only where valid is False",
    )

    coherence = None
    if frf.coherence is not None:
        coherence = _real(src, "coherence", frf.coherence)
        _require_shape(src, "coherence", coherence, shape, origin)
        _require_finite(src, "coherence", coherence, at_output)
        outside = (coherence < -COHERENCE_SLACK) | (coherence > 1 + COHERENCE_SLACK)
        if outside.any():
            idx = _first(outside)
            raise _error(
                src,
                f"coherence must lie in [0, 1], got {coherence[idx]:g} at {at_output(idx)}",
            )
        coherence = np.clip(coherence, 0.0, 1.0)

    H_var = None
    if frf.H_var is not None:
        H_var = _real(src, "H_var", frf.H_var)
        _require_shape(src, "H_var", H_var, shape, origin)
        _require_finite(src, "H_var", H_var, at_output)
        if (H_var < 0).any():
            idx = _first(H_var < 0)
            raise _error(
                src,
                f"H_var is a variance and must be >= 0, got {H_var[idx]:g} at {at_output(idx)}",
            )

    # An empty reaction list with no H_reaction is the same as "no reactions".
    has_labels = frf.reactions is not None and (
        isinstance(frf.reactions, str) or len(frf.reactions) > 0
    )
    reactions = H_reaction = None
    if frf.H_reaction is None and has_labels:
        raise _error(src, "reactions are given but H_reaction is missing")
    if frf.H_reaction is not None:
        if frf.reactions is None:
            raise _error(src, "H_reaction is given but the reactions labels are missing")
        reactions = _labels(src, "reactions", frf.reactions)
        _require_subset(src, "reactions", reactions, outputs)
        H_reaction = _complex(src, "H_reaction", frf.H_reaction)
        _require_shape(
            src,
            "H_reaction",
            H_reaction,
            (freq.size, len(reactions), len(inputs)),
            "(n_freq, n_react, n_in) from freq_hz, reactions, inputs",
        )
        _require_finite(src, "H_reaction", H_reaction, at(reactions, "reaction"))

    n_avg = None
    if frf.n_avg is not None:
        if not _is_whole(frf.n_avg) or int(frf.n_avg) < 1:
            raise _error(src, f"n_avg must be a whole number >= 1, got {frf.n_avg!r}")
        n_avg = int(frf.n_avg)

    return FRFData(
        freq_hz=freq,
        H=H,
        outputs=outputs,
        inputs=inputs,
        coherence=coherence,
        valid=valid,
        H_reaction=H_reaction,
        reactions=reactions,
        H_var=H_var,
        n_avg=n_avg,
        attrs=_extra_attrs(src, frf.attrs, _FRF_RESERVED_ATTRS),
    )


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
    with _create_h5(path, src) as f:
        _write_extra_attrs(src, f, data.attrs, _MODEL_RESERVED_ATTRS)
        f.attrs["format"] = MODEL_FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.create_dataset("M", data=data.M)
        f.create_dataset("K", data=data.K)
        if data.C is not None:
            f.create_dataset("C", data=data.C)
        _write_labels(f, "dofs", data.dofs)


def validate_model(model: Model, source: str = "model") -> Model:
    """Check a :class:`Model` against the model-file layout and return a normalised copy.

    Checks: ``dofs`` are unique strings; ``M``, ``K`` and (if present) ``C`` are real, finite,
    ``(n, n)`` with ``n = len(dofs)``; ``M`` and ``K`` are symmetric to a relative 1e-8 of
    their largest entry. ``C`` need not be symmetric.

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
    attrs = _extra_attrs(src, model.attrs, _MODEL_RESERVED_ATTRS)
    return Model(M=M, K=K, C=C, dofs=dofs, attrs=attrs)


# ----------------------------------------------------------------------------------------------
# Helpers: errors and checks
# ----------------------------------------------------------------------------------------------


def _error(src: str, problem: str) -> InputError:
    # Paths may hold newlines in principle; the CLI promise is one line per error.
    return InputError(" ".join(f"{src}: {problem}".splitlines()))


def _first(mask: np.ndarray) -> tuple[int, ...]:
    """Index of the first True entry of ``mask``."""
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _real(src: str, name: str, value: Any) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype.kind not in "fiu":
        raise _error(src, f"{name} must hold real numbers, got dtype {a.dtype}")
    return a.astype(np.float64)


def _complex(src: str, name: str, value: Any) -> np.ndarray:
    # A real H would mean the phase has been lost somewhere upstream; refuse rather than guess.
    a = np.asarray(value)
    if a.dtype.kind != "c":
        raise _error(src, f"{name} must be complex, got dtype {a.dtype}")
    return a.astype(np.complex128)


def _boolean(src: str, name: str, value: Any) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype.kind == "b":
        return a.astype(bool)
    # Tools without an HDF5 boolean type (MATLAB, LabVIEW) write 0/1 integers.
    if a.dtype.kind in "iu" and np.isin(a, (0, 1)).all():
        return a.astype(bool)
    raise _error(src, f"{name} must be boolean (or 0/1 integers), got dtype {a.dtype}")


def _require_shape(
    src: str, name: str, a: np.ndarray, shape: tuple[int, ...], origin: str
) -> None:
    if a.ndim != len(shape):
        raise _error(src, f"{name} must be {len(shape)}-D, got shape {a.shape}")
    if a.shape != shape:
        raise _error(src, f"{name} has shape {a.shape}, expected {shape} = {origin}")


def _require_finite(
    src: str,
    name: str,
    a: np.ndarray,
    where: Callable[[tuple[int, ...]], str],
    nan_ok: np.ndarray | None = None,
    hint: str = "",
) -> None:
    """Raise if ``a`` holds NaN or Inf, except NaN where ``nan_ok`` is True.

    ``where`` maps the index of the first bad value to words for the message.
    """
    bad = ~np.isfinite(a)
    if nan_ok is not None:
        bad &= ~(np.isnan(a) & nan_ok)
    if bad.any():
        idx = _first(bad)
        extra = f" ({hint})" if hint else ""
        raise _error(
            src,
            f"{name} holds NaN or Inf in {int(bad.sum())} value(s), first at {where(idx)}{extra}",
        )


def _labels(src: str, name: str, labels: Any) -> list[str]:
    """DOF labels as a list of unique ``str``; the labels themselves are never interpreted."""
    if labels is None or isinstance(labels, (str, bytes)):
        raise _error(src, f"{name} must be a list of DOF label strings, got {labels!r}")
    try:
        items = list(labels)
    except TypeError:
        raise _error(src, f"{name} must be a list of DOF label strings, got {labels!r}") from None
    for item in items:
        if not isinstance(item, str):
            raise _error(
                src, f"{name} must hold strings, found {item!r} ({type(item).__name__})"
            )
    items = [str(item) for item in items]  # np.str_ -> str
    if not items:
        raise _error(src, f"{name} is empty")
    seen: set[str] = set()
    for item in items:
        if item in seen:
            raise _error(src, f"duplicate label {item!r} in {name}")
        seen.add(item)
    return items


def _require_subset(src: str, name: str, labels: list[str], outputs: list[str]) -> None:
    # Inputs and reactions must be measured as outputs too: the SSID equations need the
    # driving-point and interface responses.
    known = set(outputs)
    for label in labels:
        if label not in known:
            raise _error(src, f"{name} label {label!r} is not among outputs")


def _is_whole(value: Any) -> bool:
    """True for a whole number (int, or a float with no fraction, as MATLAB writes them)."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, np.integer)):
        return True
    if isinstance(value, (float, np.floating)):
        return bool(np.isfinite(value)) and float(value).is_integer()
    return False


# ----------------------------------------------------------------------------------------------
# Helpers: HDF5
# ----------------------------------------------------------------------------------------------


@contextmanager
def _open_h5(path: PathLike, src: str) -> Iterator[h5py.File]:
    """Open ``path`` for reading; every low-level failure becomes a one-line InputError."""
    if not os.path.exists(path):
        raise _error(src, "no such file")
    if not os.path.isfile(path):
        raise _error(src, "not a file")
    if not os.access(path, os.R_OK):
        raise _error(src, "cannot read the file (permission denied)")
    if not h5py.is_hdf5(path):
        raise _error(src, "not an HDF5 file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:  # an HDF5 signature but a truncated or corrupt body
        raise _error(src, f"damaged HDF5 file ({exc})") from exc
    try:
        with f:
            yield f
    except OSError as exc:
        raise _error(src, f"damaged HDF5 file, cannot read its content ({exc})") from exc


@contextmanager
def _create_h5(path: PathLike, src: str) -> Iterator[h5py.File]:
    """Create ``path`` via a temporary file in the same directory and an atomic rename."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        f = h5py.File(tmp, "w")
    except OSError as exc:
        raise OSError(f"{src}: cannot create file ({exc})") from exc
    try:
        with f:
            yield f
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _check_kind(src: str, f: h5py.File, expected: str) -> None:
    fmt = _attr_str(src, f, "format")
    if fmt is None:
        raise _error(src, f"root attribute 'format' is missing (expected {expected!r})")
    if fmt != expected:
        raise _error(src, f"format is {fmt!r}, expected {expected!r}")
    if "format_version" not in f.attrs:
        raise _error(src, "root attribute 'format_version' is missing")
    version = _plain(f.attrs["format_version"])
    if not _is_whole(version) or int(version) != FORMAT_VERSION:
        raise _error(
            src, f"unsupported format_version {version!r} (this version reads {FORMAT_VERSION})"
        )


def _attr_str(src: str, f: h5py.File, name: str) -> str | None:
    if name not in f.attrs:
        return None
    value = _plain(f.attrs[name])
    if not isinstance(value, str):
        raise _error(src, f"root attribute {name!r} must be a string, got {value!r}")
    return value


def _plain(value: Any) -> Any:
    """An attribute value as plain Python where possible (str, int, float), else unchanged."""
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.reshape(()).item()  # MATLAB writes scalars as 1x1 arrays
    if isinstance(value, bytes):
        try:
            return value.decode("utf-8")
        except UnicodeDecodeError:
            return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def _dataset(src: str, f: h5py.File, name: str, required: bool) -> h5py.Dataset | None:
    obj = f.get(name)
    if obj is None:
        if required:
            raise _error(src, f"missing dataset /{name}")
        return None
    if not isinstance(obj, h5py.Dataset):
        raise _error(src, f"/{name} is not a dataset")
    if obj.shape is None:
        raise _error(src, f"/{name} is empty (null dataspace)")
    return obj


def _read_numeric(src: str, f: h5py.File, name: str, required: bool = True) -> np.ndarray | None:
    ds = _dataset(src, f, name, required)
    if ds is None:
        return None
    if h5py.check_string_dtype(ds.dtype) is not None or ds.dtype.kind not in "biufc":
        raise _error(src, f"/{name} must be numeric, got dtype {ds.dtype}")
    return np.asarray(ds[()])


def _read_labels(src: str, f: h5py.File, name: str, required: bool = True) -> list[str] | None:
    ds = _dataset(src, f, name, required)
    if ds is None:
        return None
    if h5py.check_string_dtype(ds.dtype) is None:
        raise _error(src, f"/{name} must hold DOF label strings, got dtype {ds.dtype}")
    if ds.ndim != 1:
        raise _error(src, f"/{name} must be 1-D, got shape {ds.shape}")
    try:
        return [str(s) for s in ds.asstr()[()]]
    except UnicodeDecodeError:
        raise _error(src, f"/{name} holds a label that is not valid text (UTF-8)") from None


def _write_labels(f: h5py.File, name: str, labels: list[str]) -> None:
    # Variable-length UTF-8, as the contract asks; readers in other languages rely on it.
    f.create_dataset(name, data=np.array(labels, dtype=object), dtype=h5py.string_dtype())


def _read_extra_attrs(f: h5py.File, reserved: frozenset[str]) -> dict:
    extra = {}
    for key in f.attrs:
        if key in reserved:
            continue
        try:
            extra[key] = _plain(f.attrs[key])
        except (OSError, TypeError):
            # An attribute of a type h5py cannot map is provenance we cannot use; the data
            # themselves are still fine.
            continue
    return extra


def _extra_attrs(src: str, attrs: Any, reserved: frozenset[str]) -> dict:
    if attrs is None:
        return {}
    if not isinstance(attrs, dict):
        raise _error(src, f"attrs must be a dict, got {type(attrs).__name__}")
    for key in attrs:
        if not isinstance(key, str):
            raise _error(src, f"attribute names must be strings, got {key!r}")
    return {k: v for k, v in attrs.items() if k not in reserved}


def _write_extra_attrs(src: str, f: h5py.File, attrs: dict, reserved: frozenset[str]) -> None:
    for key, value in attrs.items():
        if key in reserved:
            continue
        try:
            f.attrs[key] = value
        except (TypeError, ValueError) as exc:
            raise _error(src, f"attribute {key!r} cannot be stored in HDF5 ({exc})") from exc
