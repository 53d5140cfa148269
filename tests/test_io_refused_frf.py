"""ssid.io: every refusal of a malformed FRF file, each written good and then corrupted with
h5py, and of paths that are not FRF files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from test_io_helpers import (
    assert_corrupted_file_refused,
    assert_one_line_error,
    delete,
    labels_to,
    nan_at,
    replace_values,
    set_attr,
)

from ssid.errors import InputError
from ssid.io import read_frf, write_frf, write_model

# ----------------------------------------------------------------------------------------------
# Refused FRF files: each written good, then corrupted with h5py
# ----------------------------------------------------------------------------------------------


def _shift_freq(f):
    freq = f["freq_hz"][()]
    freq[10] = freq[9]
    f["freq_hz"][...] = freq


def _add(name, make, **kwargs):
    """Add dataset ``name`` built by ``make(H)`` from the file's own H."""

    def corrupt(f):
        f.create_dataset(name, data=make(f["H"][()]), **kwargs)

    return corrupt


def _blank_with_inf(f):
    H = f["H"][()]
    valid = np.ones(H.shape, dtype=bool)
    valid[2, 0, 0] = False
    H[2, 0, 0] = np.inf
    f["H"][...] = H
    f.create_dataset("valid", data=valid)


def _reaction_pair(labels, n_react=None):
    def corrupt(f):
        n_freq, _, n_in = f["H"].shape
        n = len(labels) if n_react is None else n_react
        f.create_dataset("H_reaction", data=np.ones((n_freq, n, n_in), complex))
        labels_to("reactions", labels)(f)

    return corrupt


def _reaction_var(make):
    """A valid reaction pair, then ``H_reaction_var = make(H_reaction)``."""

    def corrupt(f):
        _reaction_pair(["1+Z"])(f)
        f.create_dataset("H_reaction_var", data=make(f["H_reaction"][()]))

    return corrupt


def _one_nan(H):
    out = np.full(H.shape, 0.9)
    out[0, 1, 1] = np.nan
    return out


def _make_group_h(f):
    del f["H"]
    f.create_group("H")


FRF_CORRUPTIONS = [
    # file kind
    ("format-missing", delete("format"), "'format' is missing"),
    ("format-wrong", set_attr("format", "ssidlab-model"), "format is 'ssidlab-model'"),
    ("format-not-string", set_attr("format", 3), "must be a string"),
    ("version-missing", delete("format_version"), "'format_version' is missing"),
    ("version-2", set_attr("format_version", 2), "unsupported format_version 2"),
    ("quantity-missing", delete("quantity"), "'quantity' is missing"),
    ("quantity-wrong", set_attr("quantity", "receptance"), "quantity is 'receptance'"),
    # required datasets
    ("H-missing", delete("H"), "missing dataset /H"),
    ("freq-missing", delete("freq_hz"), "missing dataset /freq_hz"),
    ("outputs-missing", delete("outputs"), "missing dataset /outputs"),
    ("inputs-missing", delete("inputs"), "missing dataset /inputs"),
    ("H-is-group", _make_group_h, "/H is not a dataset"),
    # dtypes and shapes
    ("H-real", replace_values("H", lambda H: H.real), "H must be complex"),
    ("H-2d", replace_values("H", lambda H: H[:, :, 0]), "H must be 3-D"),
    (
        "H-shape-vs-outputs",
        labels_to("outputs", ["1+Z", "3+Z"]),
        "H has shape (64, 3, 2), expected (64, 2, 2)",
    ),
    (
        "H-shape-vs-freq",
        replace_values("freq_hz", lambda fr: fr[:-1]),
        "H has shape (64, 3, 2), expected (63, 3, 2)",
    ),
    ("freq-2d", replace_values("freq_hz", lambda fr: fr[:, None]), "freq_hz must be a non-empty 1-D"),
    ("freq-complex", replace_values("freq_hz", lambda fr: fr + 0j), "freq_hz must hold real numbers"),
    ("outputs-numeric", replace_values("outputs", lambda o: np.arange(3)), "/outputs must hold DOF"),
    (
        "outputs-2d",
        replace_values("outputs", lambda o: o[None, :], dtype=h5py.string_dtype()),
        "/outputs must be 1-D",
    ),
    # frequency axis
    ("freq-nan", nan_at("freq_hz"), "freq_hz holds NaN or Inf"),
    ("freq-not-increasing", _shift_freq, "strictly increasing"),
    ("freq-zero", lambda f: f["freq_hz"].__setitem__(0, 0.0), "freq_hz must be > 0"),
    # non-finite H
    ("H-nan", nan_at("H"), "H holds NaN or Inf in 1 value(s)"),
    ("H-inf", nan_at("H", np.inf), "H holds NaN or Inf"),
    ("H-inf-where-blanked", _blank_with_inf, "H holds NaN or Inf"),
    # labels
    ("outputs-duplicate", labels_to("outputs", ["1+Z", "2+Z", "1+Z"]), "duplicate label '1+Z'"),
    ("inputs-duplicate", labels_to("inputs", ["3+Z", "3+Z"]), "duplicate label '3+Z' in inputs"),
    ("input-not-output", labels_to("inputs", ["1+Z", "9+Z"]), "inputs label '9+Z' is not among"),
    # optional per-value datasets
    ("coherence-above-1", _add("coherence", lambda H: np.full(H.shape, 1.2)), "got 1.2"),
    ("coherence-negative", _add("coherence", lambda H: np.full(H.shape, -0.1)), "in [0, 1]"),
    ("coherence-nan", _add("coherence", _one_nan), "coherence holds NaN or Inf"),
    ("coherence-shape", _add("coherence", lambda H: np.ones(H.shape[:2])), "coherence must be 3-D"),
    ("valid-shape", _add("valid", lambda H: np.ones(H.shape[:2] + (1,), bool)), "valid has shape"),
    ("valid-float", _add("valid", lambda H: np.full(H.shape, 0.5)), "valid must be boolean"),
    ("H_var-shape", _add("H_var", lambda H: np.ones(H.shape[1:])), "H_var must be 3-D"),
    ("H_var-negative", _add("H_var", lambda H: -np.ones(H.shape)), "H_var is a variance"),
    ("H_var-inf", _add("H_var", lambda H: np.full(H.shape, np.inf)), "H_var holds NaN or Inf"),
    # reactions
    ("H_reaction-alone", _add("H_reaction", lambda H: H[:, :1, :]), "reactions labels are missing"),
    ("reactions-alone", labels_to("reactions", ["1+Z"]), "H_reaction is missing"),
    ("reaction-not-output", _reaction_pair(["7+Z"]), "reactions label '7+Z' is not among"),
    ("H_reaction-shape", _reaction_pair(["1+Z"], n_react=2), "(n_freq, n_react, n_in)"),
    ("H_reaction_var-alone", _add("H_reaction_var", lambda H: np.ones(H[:, :1, :].shape)),
     "H_reaction_var is given but H_reaction is missing"),
    ("H_reaction_var-shape", _reaction_var(lambda R: np.ones(R.shape[:2])), "H_reaction_var must be 3-D"),
    ("H_reaction_var-negative", _reaction_var(lambda R: -np.ones(R.shape)), "H_reaction_var is a variance"),
    ("H_reaction_var-nan", _reaction_var(lambda R: np.full(R.shape, np.nan)), "H_reaction_var holds NaN"),
    # n_avg
    ("n_avg-zero", set_attr("n_avg", 0), "n_avg must be a whole number >= 1"),
    ("n_avg-fraction", set_attr("n_avg", 2.5), "n_avg must be a whole number >= 1"),
]


@pytest.mark.parametrize(
    "corrupt, fragment", [c[1:] for c in FRF_CORRUPTIONS], ids=[c[0] for c in FRF_CORRUPTIONS]
)
def test_read_frf_refuses_malformed_file(tmp_path, frf, corrupt, fragment):
    assert_corrupted_file_refused(tmp_path / "bad.h5", write_frf, frf, read_frf, corrupt, fragment)


def test_read_frf_refuses_missing_path(tmp_path):
    with pytest.raises(InputError) as excinfo:
        read_frf(tmp_path / "nope.h5")
    assert_one_line_error(excinfo, tmp_path / "nope.h5", "no such file")


def test_read_frf_refuses_directory(tmp_path):
    with pytest.raises(InputError) as excinfo:
        read_frf(tmp_path)
    assert_one_line_error(excinfo, tmp_path, "not a file")


def test_read_frf_refuses_text_file(tmp_path):
    path = tmp_path / "notes.h5"
    path.write_text("freq,H\n1,2\n")
    with pytest.raises(InputError) as excinfo:
        read_frf(path)
    assert_one_line_error(excinfo, path, "not an HDF5 file")


def test_read_frf_refuses_uff_file_and_says_how_to_convert_it(tmp_path, frf):
    """An analyser's UFF export handed where HDF5 is read: the error names the converter."""
    from ssid.exchange.uff import write_uff_frf

    path = tmp_path / "frf.uff"
    write_uff_frf(path, frf)
    with pytest.raises(InputError) as excinfo:
        read_frf(path)
    assert_one_line_error(excinfo, path, "not an HDF5 file (it looks like a UFF universal file: "
                                         "convert it with `ssidlab convert`)")


def test_read_frf_refuses_truncated_file(tmp_path, frf):
    path = tmp_path / "cut.h5"
    write_frf(path, frf)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as excinfo:
        read_frf(path)
    assert_one_line_error(excinfo, path)


def test_read_frf_refuses_model_file(tmp_path, model):
    path = tmp_path / "model.h5"
    write_model(path, model)
    with pytest.raises(InputError) as excinfo:
        read_frf(path)
    assert_one_line_error(excinfo, path, "format is 'ssidlab-model', expected 'ssidlab-frf'")


def test_error_message_stays_one_line_with_line_break_in_label(tmp_path, frf):
    frf.outputs = ["a\nb", "a\nb", "c"]
    frf.inputs = ["c", "a\nb"]
    with pytest.raises(InputError) as excinfo:
        write_frf(tmp_path / "x.h5", frf)
    assert_one_line_error(excinfo, tmp_path / "x.h5", "duplicate label 'a\\nb'")
