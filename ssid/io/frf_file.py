"""The FRF file (``format = "ssidlab-frf"``): read, write, validate."""

from __future__ import annotations

import os

import numpy as np

from ssid.frf import FRFData, require_response

from ._common import (
    _FRF_RESERVED_ATTRS,
    COHERENCE_SLACK,
    FORMAT_VERSION,
    FRF_FORMAT,
    QUANTITY,
    PathLike,
    _attr_str,
    _boolean,
    _check_kind,
    _complex,
    _create_h5,
    _error,
    _extra_attrs,
    _first,
    _is_whole,
    _labels,
    _open_h5,
    _plain,
    _read_extra_attrs,
    _read_labels,
    _read_numeric,
    _real,
    _require_finite,
    _require_shape,
    _require_subset,
    _write_extra_attrs,
    _write_labels,
    label_frf_units,
)

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
            H_reaction_var=_read_numeric(src, f, "H_reaction_var", required=False),
            n_avg=_plain(f.attrs["n_avg"]) if "n_avg" in f.attrs else None,
            attrs=_read_extra_attrs(f, _FRF_RESERVED_ATTRS),
        )
    return validate_frf(raw, src)


def read_measured_frf(path: PathLike) -> FRFData:
    """:func:`read_frf` for an analysis: also refuses a file with no response in it.

    Besides the layout, the data must hold something to analyse (see
    :func:`ssid.frf.require_response`): valid values, a response at every output and input
    (no dead channel) and magnitudes of an accelerance in SI units. Conversion between
    formats uses :func:`read_frf`, which carries such files through unchanged.
    """
    frf = read_frf(path)
    require_response(frf, os.fspath(path))
    return frf


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
    with _create_h5(path) as f:
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
        for name in ("coherence", "valid", "H_var", "H_reaction", "H_reaction_var"):
            value = getattr(data, name)
            if value is not None:
                f.create_dataset(name, data=value)
        if data.reactions is not None:
            _write_labels(f, "reactions", data.reactions)
        label_frf_units(f)


def validate_frf(frf: FRFData, source: str = "FRF data") -> FRFData:
    """Check an :class:`FRFData` against the FRF-file layout and return a normalised copy.

    Checks: labels are unique strings, every input and reaction label is an output label;
    ``freq_hz`` is 1-D, finite, > 0 and strictly increasing; ``H`` is complex with shape
    ``(n_freq, n_out, n_in)``; ``coherence``, ``valid`` and ``H_var`` have the shape of ``H``;
    ``H_reaction`` is complex ``(n_freq, n_react, n_in)`` and comes with ``reactions``; no NaN
    or Inf anywhere, except NaN in ``H`` where ``valid`` is False (blanked values);
    ``0 <= coherence <= 1``; ``H_var >= 0``; ``H_reaction_var`` (with ``H_reaction``, its shape) ``>= 0``; ``n_avg`` is a whole number >= 1.

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
    blanked = None if valid is None else ~valid
    _require_finite(
        src,
        "H",
        H,
        at_output,
        nan_ok=blanked,
        hint="NaN is allowed only where valid is False",
    )

    coherence = None
    if frf.coherence is not None:
        coherence = _real(src, "coherence", frf.coherence)
        _require_shape(src, "coherence", coherence, shape, origin)
        # A blanked value's coherence and variance are skipped with it (as NaN in H is):
        # read as 0, "no estimate".
        _require_finite(src, "coherence", coherence, at_output, nan_ok=blanked,
                        hint="NaN is allowed only where valid is False")
        coherence = np.nan_to_num(coherence, nan=0.0)
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
        _require_finite(src, "H_var", H_var, at_output, nan_ok=blanked,
                        hint="NaN is allowed only where valid is False")
        H_var = np.nan_to_num(H_var, nan=0.0)
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
    H_reaction_var = None
    if frf.H_reaction_var is not None:
        if H_reaction is None:
            raise _error(src, "H_reaction_var is given but H_reaction is missing")
        H_reaction_var = _real(src, "H_reaction_var", frf.H_reaction_var)
        _require_shape(src, "H_reaction_var", H_reaction_var, H_reaction.shape,
                       "the shape of H_reaction")
        _require_finite(src, "H_reaction_var", H_reaction_var, at(reactions, "reaction"))
        if (H_reaction_var < 0).any():
            idx = _first(H_reaction_var < 0)
            raise _error(src, f"H_reaction_var is a variance and must be >= 0, got "
                              f"{H_reaction_var[idx]:g} at {at(reactions, 'reaction')(idx)}")

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
        H_reaction_var=H_reaction_var,
        attrs=_extra_attrs(src, frf.attrs, _FRF_RESERVED_ATTRS),
    )


