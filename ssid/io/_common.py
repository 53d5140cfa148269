"""Shared pieces of the file readers: constants, validation helpers and HDF5 access."""

from __future__ import annotations

import errno
import io
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import h5py
import numpy as np

from ssid.errors import InputError
from ssid.files import written_atomically

PathLike = str | os.PathLike

FRF_FORMAT = "ssidlab-frf"
MODEL_FORMAT = "ssidlab-model"
FORMAT_VERSION = 1
QUANTITY = "accelerance"
#: The SI units of the FRF file's datasets (contract), written as each dataset's ``units``
#: attribute so that a file read without the contract at hand says what it holds; H_var is
#: E|H - H_true|^2 (complex), so it carries H's units squared.
FRF_DATASET_UNITS = {"freq_hz": "Hz", "H": "(m/s^2)/N", "H_var": "((m/s^2)/N)^2", "coherence": "1",
                     "H_reaction": "N/N", "H_reaction_var": "(N/N)^2"}


def label_frf_units(f: h5py.File) -> None:
    """Set the ``units`` attribute of each FRF dataset present in ``f`` (:data:`FRF_DATASET_UNITS`)."""
    for name, units in FRF_DATASET_UNITS.items():
        if name in f:
            f[name].attrs["units"] = units

# M and K come from FE codes or from our own identification; both are symmetric up to
# round-off, so anything beyond this relative level is a wrong file, not numerics. Round-off
# includes an exporter's: float32 (6e-8 of an entry) or text with 7 significant digits
# (5e-7); at 1e-8 a contract check's K with 1e-7 of asymmetry was refused. Matrices
# accepted are made exactly symmetric, so that every user of the model sees the same one.
SYMMETRY_RTOL = 1e-6
# Coherence estimates |Gxy|^2 / (Gxx Gyy) can land a few ulp outside [0, 1]; such values are
# accepted and clipped rather than making a whole measurement unreadable.
COHERENCE_SLACK = 1e-9

# Root attributes that the layouts themselves define; FRFData.attrs / Model.attrs never
# override them on write and never contain them after a read.
_FRF_RESERVED_ATTRS = frozenset({"format", "format_version", "quantity", "n_avg"})
_MODEL_RESERVED_ATTRS = frozenset({"format", "format_version"})



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
    for k, item in enumerate(items):
        if not item.strip():  # no DOF: FRFs would be matched (or not) by a blank
            raise _error(src, f"{name}[{k}] is an empty label")
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


def _uff_hint(path: PathLike) -> str:
    """A hint when a file that should be HDF5 opens like a universal file: engineers hand us
    the UFF their analyser wrote, and the readers here take HDF5 only."""
    try:
        with open(path, "rb") as fh:
            first = fh.read(256).split(None, 1)[:1]
    except OSError:
        return ""
    if first == [b"-1"]:  # a UFF dataset opens with a line holding "-1" alone
        return " (it looks like a UFF universal file: convert it with `ssidlab convert`)"
    return ""


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
        raise _error(src, "not an HDF5 file" + _uff_hint(path))
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        if not _locked_by_a_writer(exc):  # an HDF5 signature but a truncated or corrupt body
            raise _error(src, f"damaged HDF5 file ({exc})") from exc
        # A running acquisition holds its run file for writing, and the file is meant to be
        # read meanwhile (flushed after every line, docs/acquisition.md); HDF5's lock would
        # refuse any reader. Read-only, nothing is lost by not taking the lock.
        try:
            f = h5py.File(path, "r", locking=False)
        except OSError as exc2:
            raise _error(src, "in use by another process (a running acquisition?) and not readable at "
                              f"this moment; try again ({exc2})") from exc2
    try:
        with f:
            yield f
    except OSError as exc:
        raise _error(src, f"damaged HDF5 file, cannot read its content ({exc})") from exc
    except (RuntimeError, UnicodeDecodeError) as exc:
        # HDF5 reports damage inside a file's metadata (a bad B-tree signature, an attribute
        # that runs off its buffer) as RuntimeError, and a mangled type name as a decode error;
        # only those raised inside h5py are the file's, any other is a bug of ours.
        if not _raised_in_h5py(exc):
            raise
        raise _error(src, f"damaged HDF5 file, cannot read its content ({type(exc).__name__}: {exc})") from exc


def _locked_by_a_writer(exc: OSError) -> bool:
    """Whether h5py's ``exc`` is HDF5's file lock refusing a reader (another process writes)."""
    return exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK) or "unable to lock file" in str(exc)


def _raised_in_h5py(exc: BaseException) -> bool:
    """Whether the innermost frame of ``exc``'s traceback is h5py's (its Cython modules too)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and f"h5py{os.sep}" in tb.tb_frame.f_code.co_filename


@contextmanager
def _create_h5(path: PathLike) -> Iterator[h5py.File]:
    """Create ``path``: the file is built in memory, then its bytes are written to a temporary
    file in the same directory and renamed onto ``path``.

    Not HDF5 writing to the disk itself: on a full disk (or past a file-size limit) HDF5
    reports the failed write while the file is closed, where h5py only prints it, so a
    half-written file was renamed into place, and the library's state then crashed the
    interpreter at exit (exit 139). Written from memory, the failure is an ordinary write's
    OSError, which names the file. The files are small (matrices, FRFs: megabytes).
    """
    image = io.BytesIO()
    with h5py.File(image, "w") as f:
        yield f
    with written_atomically(path) as tmp:
        tmp.write_bytes(image.getbuffer())


def read_format(path: PathLike) -> str | None:
    """The root ``format`` attribute of an HDF5 file (None when it has none), opened as the
    readers open files: a damaged file, or one another process writes, as they say."""
    src = os.fspath(path)
    with _open_h5(path, src) as f:
        if "format" not in f.attrs:
            list(f.attrs.keys())  # h5py also says "absent" of damaged attributes; listing raises
            return None
        return _attr_str(src, f, "format")


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
            # h5py's get() says "absent" also when the group's index is damaged; listing the
            # group then raises, in h5py (_open_h5 calls that damage).
            list(f.keys())
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

