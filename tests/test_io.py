"""ssid.io: round trips of the FRF and model files, and every refusal of a malformed file."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from ssid.errors import InputError
from ssid.frf import FRFData
from ssid.io import (
    FRF_FORMAT,
    MODEL_FORMAT,
    Model,
    read_frf,
    read_model,
    validate_frf,
    write_frf,
    write_model,
)


def assert_one_line_error(excinfo, path, *fragments: str) -> None:
    """The message is one line, names the file and contains each fragment."""
    message = str(excinfo.value)
    assert "\n" not in message and "\r" not in message
    assert message.startswith(str(path))
    for fragment in fragments:
        assert fragment in message, message


def replace_dataset(f: h5py.File, name: str, data, **kwargs) -> None:
    del f[name]
    f.create_dataset(name, data=data, **kwargs)


# ----------------------------------------------------------------------------------------------
# Round trips
# ----------------------------------------------------------------------------------------------


def test_frf_round_trip_minimal(tmp_path, frf):
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    back = read_frf(path)

    np.testing.assert_array_equal(back.freq_hz, frf.freq_hz)
    np.testing.assert_array_equal(back.H, frf.H)
    assert back.outputs == frf.outputs and back.inputs == frf.inputs
    assert all(type(lbl) is str for lbl in back.outputs + back.inputs)
    for name in ("coherence", "valid", "H_reaction", "reactions", "H_var", "n_avg", "H_reaction_var"):
        assert getattr(back, name) is None, name
    assert back.attrs == {}


def test_frf_file_layout_follows_contract(tmp_path, frf_full):
    path = tmp_path / "frf.h5"
    write_frf(path, frf_full)
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == FRF_FORMAT
        assert f.attrs["format_version"] == 1
        assert f.attrs["quantity"] == "accelerance"
        assert f.attrs["n_avg"] == 20
        assert f["freq_hz"].dtype == np.float64
        assert f["H"].dtype == np.complex128
        assert f["H_reaction"].dtype == np.complex128
        assert f["valid"].dtype == bool
        for name in ("outputs", "inputs", "reactions"):
            info = h5py.check_string_dtype(f[name].dtype)
            assert info is not None and info.length is None and info.encoding == "utf-8"


def test_frf_round_trip_with_all_optional_items(tmp_path, frf_full):
    path = tmp_path / "frf.h5"
    write_frf(path, frf_full)
    back = read_frf(path)

    np.testing.assert_array_equal(back.H, frf_full.H)  # NaN at the blanked value compares equal
    assert np.isnan(back.H[5, 1, 0]) and not back.valid[5, 1, 0]
    for name in ("freq_hz", "coherence", "valid", "H_reaction", "H_var", "H_reaction_var"):
        np.testing.assert_array_equal(getattr(back, name), getattr(frf_full, name), err_msg=name)
    assert back.reactions == ["1+Z"]
    assert back.n_avg == 20
    assert back.attrs == {"operator": "test bench", "temperature_c": 21.5}


def test_labels_are_opaque_strings(tmp_path, frf):
    # Any string is a label: unicode, spaces, punctuation, even a line break.
    odd = ["Knoten 4 +Z (µ-Sensor)", "17+RX", "a\nb"]
    frf.outputs = odd
    frf.inputs = [odd[2], odd[0]]
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    back = read_frf(path)
    assert back.outputs == odd and back.inputs == [odd[2], odd[0]]


def test_required_attrs_are_not_overwritten_by_extra_attrs(tmp_path, frf):
    frf.attrs = {"format": "bogus", "format_version": 7, "quantity": "receptance", "rig": "B2"}
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    back = read_frf(path)
    assert back.attrs == {"rig": "B2"}
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == FRF_FORMAT and f.attrs["format_version"] == 1


def test_coherence_rounding_slack_is_clipped(tmp_path, frf):
    frf.coherence = np.full(frf.H.shape, 1.0 + 1e-15)
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    assert read_frf(path).coherence.max() == 1.0


def test_valid_as_0_1_integers_is_accepted(tmp_path, frf):
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    mask = np.ones(frf.H.shape, dtype=np.uint8)
    mask[0, 0, 0] = 0
    with h5py.File(path, "r+") as f:
        f.create_dataset("valid", data=mask)
    back = read_frf(path)
    assert back.valid.dtype == bool and not back.valid[0, 0, 0] and back.valid.sum() == mask.sum()


def test_nan_in_h_allowed_where_valid_is_false(tmp_path, frf):
    frf.valid = np.ones(frf.H.shape, dtype=bool)
    frf.valid[3, :, 1] = False
    frf.H = frf.H.copy()
    frf.H[3, :, 1] = np.nan
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    back = read_frf(path)
    assert np.isnan(back.H[3, :, 1]).all()
    assert np.isfinite(back.H[back.valid]).all()


@pytest.mark.parametrize("with_c", [True, False])
def test_model_round_trip(tmp_path, model, with_c):
    if not with_c:
        model.C = None
    model.attrs = {"source": "FE model rev 3"}
    path = tmp_path / "model.h5"
    write_model(path, model)
    back = read_model(path)

    np.testing.assert_array_equal(back.M, model.M)
    np.testing.assert_array_equal(back.K, model.K)
    if with_c:
        np.testing.assert_array_equal(back.C, model.C)
    else:
        assert back.C is None
    assert back.dofs == model.dofs and back.n == 3
    assert back.attrs == {"source": "FE model rev 3"}
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == MODEL_FORMAT and f.attrs["format_version"] == 1
        assert ("C" in f) == with_c


def test_model_symmetric_within_round_off_is_accepted(tmp_path, model):
    model.K = model.K.copy()
    model.K[0, 1] *= 1 + 1e-12
    write_model(tmp_path / "m.h5", model)
    assert read_model(tmp_path / "m.h5").K[0, 1] == model.K[0, 1]


def test_validate_frf_normalises_types(frf):
    frf.freq_hz = [float(x) for x in frf.freq_hz]
    frf.outputs = tuple(np.array(frf.outputs))  # np.str_ items
    out = validate_frf(frf)
    assert out.freq_hz.dtype == np.float64
    assert all(type(lbl) is str for lbl in out.outputs)


# ----------------------------------------------------------------------------------------------
# Refused FRF files: each written good, then corrupted with h5py
# ----------------------------------------------------------------------------------------------


def _shift_freq(f):
    freq = f["freq_hz"][()]
    freq[10] = freq[9]
    f["freq_hz"][...] = freq


def _nan_at(name, value=np.nan):
    def corrupt(f):
        a = f[name][()]
        a.flat[7] = value
        f[name][...] = a

    return corrupt


def _set_attr(key, value):
    def corrupt(f):
        f.attrs[key] = value

    return corrupt


def _del(name):
    def corrupt(f):
        if name in f:
            del f[name]
        else:
            del f.attrs[name]

    return corrupt


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


def _labels_to(name, labels):
    """Set string dataset ``name`` to ``labels``, creating it if absent."""

    def corrupt(f):
        if name in f:
            del f[name]
        f.create_dataset(name, data=np.array(labels, dtype=object), dtype=h5py.string_dtype())

    return corrupt


def _replace(name, make, **kwargs):
    """Replace dataset ``name`` by ``make(old_values)``."""

    def corrupt(f):
        replace_dataset(f, name, make(f[name][()]), **kwargs)

    return corrupt


def _reaction_pair(labels, n_react=None):
    def corrupt(f):
        n_freq, _, n_in = f["H"].shape
        n = len(labels) if n_react is None else n_react
        f.create_dataset("H_reaction", data=np.ones((n_freq, n, n_in), complex))
        _labels_to("reactions", labels)(f)

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
    ("format-missing", _del("format"), "'format' is missing"),
    ("format-wrong", _set_attr("format", "ssidlab-model"), "format is 'ssidlab-model'"),
    ("format-not-string", _set_attr("format", 3), "must be a string"),
    ("version-missing", _del("format_version"), "'format_version' is missing"),
    ("version-2", _set_attr("format_version", 2), "unsupported format_version 2"),
    ("quantity-missing", _del("quantity"), "'quantity' is missing"),
    ("quantity-wrong", _set_attr("quantity", "receptance"), "quantity is 'receptance'"),
    # required datasets
    ("H-missing", _del("H"), "missing dataset /H"),
    ("freq-missing", _del("freq_hz"), "missing dataset /freq_hz"),
    ("outputs-missing", _del("outputs"), "missing dataset /outputs"),
    ("inputs-missing", _del("inputs"), "missing dataset /inputs"),
    ("H-is-group", _make_group_h, "/H is not a dataset"),
    # dtypes and shapes
    ("H-real", _replace("H", lambda H: H.real), "H must be complex"),
    ("H-2d", _replace("H", lambda H: H[:, :, 0]), "H must be 3-D"),
    (
        "H-shape-vs-outputs",
        _labels_to("outputs", ["1+Z", "3+Z"]),
        "H has shape (64, 3, 2), expected (64, 2, 2)",
    ),
    (
        "H-shape-vs-freq",
        _replace("freq_hz", lambda fr: fr[:-1]),
        "H has shape (64, 3, 2), expected (63, 3, 2)",
    ),
    ("freq-2d", _replace("freq_hz", lambda fr: fr[:, None]), "freq_hz must be a non-empty 1-D"),
    ("freq-complex", _replace("freq_hz", lambda fr: fr + 0j), "freq_hz must hold real numbers"),
    ("outputs-numeric", _replace("outputs", lambda o: np.arange(3)), "/outputs must hold DOF"),
    (
        "outputs-2d",
        _replace("outputs", lambda o: o[None, :], dtype=h5py.string_dtype()),
        "/outputs must be 1-D",
    ),
    # frequency axis
    ("freq-nan", _nan_at("freq_hz"), "freq_hz holds NaN or Inf"),
    ("freq-not-increasing", _shift_freq, "strictly increasing"),
    ("freq-zero", lambda f: f["freq_hz"].__setitem__(0, 0.0), "freq_hz must be > 0"),
    # non-finite H
    ("H-nan", _nan_at("H"), "H holds NaN or Inf in 1 value(s)"),
    ("H-inf", _nan_at("H", np.inf), "H holds NaN or Inf"),
    ("H-inf-where-blanked", _blank_with_inf, "H holds NaN or Inf"),
    # labels
    ("outputs-duplicate", _labels_to("outputs", ["1+Z", "2+Z", "1+Z"]), "duplicate label '1+Z'"),
    ("inputs-duplicate", _labels_to("inputs", ["3+Z", "3+Z"]), "duplicate label '3+Z' in inputs"),
    ("input-not-output", _labels_to("inputs", ["1+Z", "9+Z"]), "inputs label '9+Z' is not among"),
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
    ("reactions-alone", _labels_to("reactions", ["1+Z"]), "H_reaction is missing"),
    ("reaction-not-output", _reaction_pair(["7+Z"]), "reactions label '7+Z' is not among"),
    ("H_reaction-shape", _reaction_pair(["1+Z"], n_react=2), "(n_freq, n_react, n_in)"),
    ("H_reaction_var-alone", _add("H_reaction_var", lambda H: np.ones(H[:, :1, :].shape)),
     "H_reaction_var is given but H_reaction is missing"),
    ("H_reaction_var-shape", _reaction_var(lambda R: np.ones(R.shape[:2])), "H_reaction_var must be 3-D"),
    ("H_reaction_var-negative", _reaction_var(lambda R: -np.ones(R.shape)), "H_reaction_var is a variance"),
    ("H_reaction_var-nan", _reaction_var(lambda R: np.full(R.shape, np.nan)), "H_reaction_var holds NaN"),
    # n_avg
    ("n_avg-zero", _set_attr("n_avg", 0), "n_avg must be a whole number >= 1"),
    ("n_avg-fraction", _set_attr("n_avg", 2.5), "n_avg must be a whole number >= 1"),
]


@pytest.mark.parametrize(
    "corrupt, fragment", [c[1:] for c in FRF_CORRUPTIONS], ids=[c[0] for c in FRF_CORRUPTIONS]
)
def test_read_frf_refuses_malformed_file(tmp_path, frf, corrupt, fragment):
    path = tmp_path / "bad.h5"
    write_frf(path, frf)
    with h5py.File(path, "r+") as f:
        corrupt(f)
    with pytest.raises(InputError) as excinfo:
        read_frf(path)
    assert_one_line_error(excinfo, path, fragment)


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


# ----------------------------------------------------------------------------------------------
# The writers refuse what the readers would refuse, and leave no file behind
# ----------------------------------------------------------------------------------------------


def _frf_with(**changes):
    def make(frf: FRFData) -> FRFData:
        for key, value in changes.items():
            setattr(frf, key, value(frf) if callable(value) else value)
        return frf

    return make


def _nan_h(frf):
    H = frf.H.copy()
    H[0, 0, 0] = np.nan
    return H


BAD_FRF_DATA = [
    ("H-nan", _frf_with(H=_nan_h), "H holds NaN or Inf"),
    ("input-not-output", _frf_with(inputs=["1+Z", "4+Z"]), "not among outputs"),
    ("freq-decreasing", _frf_with(freq_hz=lambda f: f.freq_hz[::-1]), "strictly increasing"),
    ("outputs-one-string", _frf_with(outputs="1+Z"), "list of DOF label strings"),
    ("label-not-string", _frf_with(outputs=["1+Z", 2, "3+Z"]), "must hold strings"),
    ("attr-unstorable", _frf_with(attrs={"note": {"nested": 1}}), "'note' cannot be stored"),
]


@pytest.mark.parametrize(
    "change, fragment", [c[1:] for c in BAD_FRF_DATA], ids=[c[0] for c in BAD_FRF_DATA]
)
def test_write_frf_refuses_bad_data(tmp_path, frf, change, fragment):
    path = tmp_path / "out.h5"
    with pytest.raises(InputError) as excinfo:
        write_frf(path, change(frf))
    assert_one_line_error(excinfo, path, fragment)
    assert list(tmp_path.iterdir()) == []  # neither the file nor a temporary is left


def test_write_frf_keeps_existing_file_when_refused(tmp_path, frf):
    path = tmp_path / "out.h5"
    write_frf(path, frf)
    before = path.read_bytes()
    frf.attrs = {"bad": object()}
    with pytest.raises(InputError):
        write_frf(path, frf)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out.h5"]


def test_write_to_missing_directory_raises_oserror_naming_file(tmp_path, frf):
    path = tmp_path / "no" / "such" / "dir.h5"
    with pytest.raises(OSError) as excinfo:
        write_frf(path, frf)
    assert str(path) in str(excinfo.value)


# ----------------------------------------------------------------------------------------------
# Refused model files and model data
# ----------------------------------------------------------------------------------------------


def _asym(name, rel):
    def corrupt(f):
        A = f[name][()]
        A[0, 1] += rel * np.abs(A).max()
        f[name][...] = A

    return corrupt


MODEL_CORRUPTIONS = [
    ("format-wrong", _set_attr("format", FRF_FORMAT), "format is 'ssidlab-frf'"),
    ("version-wrong", _set_attr("format_version", 3), "unsupported format_version 3"),
    ("M-missing", _del("M"), "missing dataset /M"),
    ("K-missing", _del("K"), "missing dataset /K"),
    ("dofs-missing", _del("dofs"), "missing dataset /dofs"),
    ("M-not-square", _replace("M", lambda M: np.ones((3, 2))), "M must be a square matrix"),
    ("M-1d", _replace("M", lambda M: np.ones(3)), "M must be a square matrix"),
    ("K-vs-dofs", _replace("K", lambda K: np.eye(4)), "K is 4 x 4 but there are 3 dofs"),
    ("C-vs-dofs", _replace("C", lambda C: np.eye(2)), "C is 2 x 2 but there are 3 dofs"),
    ("dofs-vs-M", _labels_to("dofs", ["1+Z", "2+Z"]), "M is 3 x 3 but there are 2 dofs"),
    ("dofs-duplicate", _labels_to("dofs", ["1+Z", "2+Z", "2+Z"]), "duplicate label '2+Z' in dofs"),
    ("M-complex", _replace("M", lambda M: M + 0j), "M must hold real numbers"),
    ("M-not-symmetric", _asym("M", 1e-6), "M is not symmetric"),
    ("K-not-symmetric", _asym("K", 1e-6), "K is not symmetric"),
    ("K-nan", _nan_at("K"), "K holds NaN or Inf in 1 value(s), first at row '3+Z', column '2+Z'"),
    ("C-inf", _nan_at("C", -np.inf), "C holds NaN or Inf"),
]


@pytest.mark.parametrize(
    "corrupt, fragment", [c[1:] for c in MODEL_CORRUPTIONS], ids=[c[0] for c in MODEL_CORRUPTIONS]
)
def test_read_model_refuses_malformed_file(tmp_path, model, corrupt, fragment):
    path = tmp_path / "bad_model.h5"
    write_model(path, model)
    with h5py.File(path, "r+") as f:
        corrupt(f)
    with pytest.raises(InputError) as excinfo:
        read_model(path)
    assert_one_line_error(excinfo, path, fragment)


def test_write_model_refuses_asymmetric_k(tmp_path, model):
    model.K = model.K.copy()
    model.K[0, 2] = 5.0
    path = tmp_path / "m.h5"
    with pytest.raises(InputError) as excinfo:
        write_model(path, model)
    assert_one_line_error(excinfo, path, "K is not symmetric", "('1+Z', '3+Z')")
    assert not path.exists()


def test_write_model_allows_asymmetric_c(tmp_path, model):
    model.C = model.C.copy()
    model.C[0, 1] += 1.0
    write_model(tmp_path / "m.h5", model)
    np.testing.assert_array_equal(read_model(tmp_path / "m.h5").C, model.C)


def test_model_n_property():
    assert Model(M=np.eye(2), K=np.eye(2), C=None, dofs=["a", "b"]).n == 2


def test_files_are_plain_paths_or_strings(tmp_path, frf, model):
    write_frf(str(tmp_path / "f.h5"), frf)
    write_model(Path(tmp_path / "m.h5"), model)
    assert read_frf(str(tmp_path / "f.h5")).n_freq == frf.n_freq
    assert read_model(tmp_path / "m.h5").n == 3
