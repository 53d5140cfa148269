"""ssid.io: round trips of the FRF and model files, the writers' refusals and every refusal of a
malformed model file (malformed FRF files: test_io_refused_frf.py)."""

from __future__ import annotations

from pathlib import Path

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


def test_nan_in_coherence_and_variance_allowed_where_valid_is_false(tmp_path, frf):
    """A blanked value's coherence and variance are skipped with it, as NaN in its H is (a
    contract check found NaN in H accepted there and NaN in coherence refused); read as 0.
    Where the value is valid they are still refused."""
    frf.valid = np.ones(frf.H.shape, dtype=bool)
    frf.valid[3, :, 1] = False
    frf.coherence = np.full(frf.H.shape, 0.99)
    frf.H_var = np.full(frf.H.shape, 1e-6)
    frf.coherence[3, :, 1] = np.nan
    frf.H_var[3, :, 1] = np.nan
    write_frf(tmp_path / "frf.h5", frf)
    back = read_frf(tmp_path / "frf.h5")
    assert (back.coherence[3, :, 1] == 0).all() and (back.H_var[3, :, 1] == 0).all()
    assert (back.coherence[back.valid] == 0.99).all()
    frf.coherence[2, 0, 0] = np.nan
    with pytest.raises(InputError, match="coherence holds NaN"):
        write_frf(tmp_path / "bad.h5", frf)


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


@pytest.mark.parametrize("rel", [1e-12, 1e-7])
def test_model_symmetric_within_round_off_is_accepted(tmp_path, model, rel):
    """Within an exporter's rounding (1e-7 of the largest entry: float32, or text of 7
    significant digits; a contract check's file was refused at 1e-8), read as (K + K^T)/2."""
    K = model.K.copy()
    model.K = model.K.copy()
    model.K[0, 1] += rel * np.abs(K).max()
    write_model(tmp_path / "m.h5", model)
    back = read_model(tmp_path / "m.h5").K
    np.testing.assert_array_equal(back, back.T)
    assert back[0, 1] == pytest.approx(K[0, 1] + rel * np.abs(K).max() / 2, rel=1e-12)


def test_validate_frf_normalises_types(frf):
    frf.freq_hz = [float(x) for x in frf.freq_hz]
    frf.outputs = tuple(np.array(frf.outputs))  # np.str_ items
    out = validate_frf(frf)
    assert out.freq_hz.dtype == np.float64
    assert all(type(lbl) is str for lbl in out.outputs)


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
    ("format-wrong", set_attr("format", FRF_FORMAT), "format is 'ssidlab-frf'"),
    ("version-wrong", set_attr("format_version", 3), "unsupported format_version 3"),
    ("M-missing", delete("M"), "missing dataset /M"),
    ("K-missing", delete("K"), "missing dataset /K"),
    ("dofs-missing", delete("dofs"), "missing dataset /dofs"),
    ("M-not-square", replace_values("M", lambda M: np.ones((3, 2))), "M must be a square matrix"),
    ("M-1d", replace_values("M", lambda M: np.ones(3)), "M must be a square matrix"),
    ("K-vs-dofs", replace_values("K", lambda K: np.eye(4)), "K is 4 x 4 but there are 3 dofs"),
    ("C-vs-dofs", replace_values("C", lambda C: np.eye(2)), "C is 2 x 2 but there are 3 dofs"),
    ("dofs-vs-M", labels_to("dofs", ["1+Z", "2+Z"]), "M is 3 x 3 but there are 2 dofs"),
    ("dofs-duplicate", labels_to("dofs", ["1+Z", "2+Z", "2+Z"]), "duplicate label '2+Z' in dofs"),
    ("M-complex", replace_values("M", lambda M: M + 0j), "M must hold real numbers"),
    ("M-not-symmetric", _asym("M", 1e-5), "M is not symmetric"),
    ("K-not-symmetric", _asym("K", 1e-5), "K is not symmetric"),
    ("K-nan", nan_at("K"), "K holds NaN or Inf in 1 value(s), first at row '3+Z', column '2+Z'"),
    ("C-inf", nan_at("C", -np.inf), "C holds NaN or Inf"),
]


@pytest.mark.parametrize(
    "corrupt, fragment", [c[1:] for c in MODEL_CORRUPTIONS], ids=[c[0] for c in MODEL_CORRUPTIONS]
)
def test_read_model_refuses_malformed_file(tmp_path, model, corrupt, fragment):
    assert_corrupted_file_refused(
        tmp_path / "bad_model.h5", write_model, model, read_model, corrupt, fragment
    )


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
