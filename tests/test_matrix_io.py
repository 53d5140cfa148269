"""Reading analysis matrices: ssidlab-model, MATLAB .mat (v5 and v7.3), Nastran OP4."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import scipy.io
import scipy.sparse

from ssid.errors import InputError
from ssid.io import Model, write_model
from ssid.matrix_io import labels_from_grid_components, read_analysis_model

M = np.diag([1.0, 2.0, 3.0])
K = np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]]) * 1e4
C = 1e-4 * K
LABELS = ["4+Z", "8+Z", "18+Z"]
PAIRS = np.array([[4, 3], [8, 3], [18, 3]])


def _check(model, damped=False):
    np.testing.assert_array_equal(model.M, M)
    np.testing.assert_array_equal(model.K, K)
    assert model.dofs == LABELS
    if damped:
        np.testing.assert_array_equal(model.C, C)
    else:
        assert model.C is None


def test_model_file(tmp_path):
    p = tmp_path / "m.h5"
    write_model(p, Model(M, K, C, LABELS))
    _check(read_analysis_model(p), damped=True)


@pytest.mark.parametrize("labels", [np.array(LABELS, dtype=object), np.array(LABELS), PAIRS])
def test_mat_v5_with_labels_as_cell_char_or_grid_pairs(tmp_path, labels):
    p = tmp_path / "m.mat"
    scipy.io.savemat(p, {"MAA": M, "KAA": scipy.sparse.csc_matrix(K), "BAA": C, "dofs": labels})
    _check(read_analysis_model(p), damped=True)


def test_mat_v73_hdf5(tmp_path):
    # MATLAB -v7.3 layout: 512-byte user block starting "MATLAB 7.3 MAT-file", column-major
    # datasets with a MATLAB_class attribute, char arrays as uint16, cells as references.
    p = tmp_path / "m73.mat"
    with h5py.File(p, "w", userblock_size=512) as f:
        f.create_dataset("M", data=M.T).attrs["MATLAB_class"] = np.bytes_("double")
        g = f.create_group("K")
        Kc = scipy.sparse.csc_matrix(K)
        g.create_dataset("data", data=Kc.data)
        g.create_dataset("ir", data=Kc.indices.astype(np.uint64))
        g.create_dataset("jc", data=Kc.indptr.astype(np.uint64))
        g.attrs["MATLAB_class"] = np.bytes_("double")
        g.attrs["MATLAB_sparse"] = np.uint64(3)
        refs = f.create_group("#refs#")
        ref_list = []
        for k, lbl in enumerate(LABELS):
            d = refs.create_dataset(f"s{k}", data=np.array([[ord(c)] for c in lbl], dtype=np.uint16))
            d.attrs["MATLAB_class"] = np.bytes_("char")
            ref_list.append(d.ref)
        cell = f.create_dataset("dofs", data=np.array([ref_list]).T, dtype=h5py.ref_dtype)
        cell.attrs["MATLAB_class"] = np.bytes_("cell")
    with open(p, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" "))
    _check(read_analysis_model(p))


@pytest.mark.parametrize("binary", [False, True])
def test_op4_through_pyyeti(tmp_path, binary):
    op4 = pytest.importorskip("pyyeti.nastran.op4")
    p = tmp_path / "m.op4"
    op4.write(str(p), {"MAA": M, "KAA": K, "DOFS": PAIRS.astype(float)}, binary=binary)
    _check(read_analysis_model(p))


def test_explicit_names_and_labels(tmp_path):
    p = tmp_path / "m.mat"
    scipy.io.savemat(p, {"MGG": M, "MAA": 2 * M, "KGG": K})
    with pytest.raises(InputError, match="several mass matrices"):
        read_analysis_model(p, dofs=LABELS)
    _check(read_analysis_model(p, mass="MGG", dofs=LABELS))


def test_grid_component_labels():
    assert labels_from_grid_components(np.array([[17, 4], [9, 0], [3, 6]])) == ["17+RX", "9", "3+RZ"]
    with pytest.raises(ValueError, match="0-6"):
        labels_from_grid_components(np.array([[1, 7]]))
    # gave "-1+Z", which place and correlate took and every export refused later (QA)
    with pytest.raises(ValueError, match="grid -1 is not a Nastran grid ID"):
        labels_from_grid_components(np.array([[2, 3], [-1, 3]]))


@pytest.mark.parametrize(
    "content, match",
    [
        ({"K": K, "dofs": PAIRS}, "no mass matrix"),
        ({"M": M, "K": K}, "no DOF labels"),
        ({"M": M, "K": K, "dofs": np.ones((3, 3))}, "dofs must be"),
        ({"M": M, "K": K + np.triu(np.ones((3, 3)), 1), "dofs": PAIRS}, "not symmetric"),
        ({"M": M, "K": K * np.nan, "dofs": PAIRS}, "NaN"),
        ({"M": M[:2, :2], "K": K, "dofs": PAIRS}, "2 x 2 but there are 3 dofs"),
        ({"M": M, "K": K, "dofs": np.array([[4, 3], [4, 3], [5, 3]])}, "duplicate"),
    ],
)
def test_bad_mat_content_is_one_line_input_error(tmp_path, content, match):
    p = tmp_path / "bad.mat"
    scipy.io.savemat(p, content)
    with pytest.raises(InputError, match=match) as exc:
        read_analysis_model(p)
    assert "\n" not in str(exc.value) and str(exc.value).startswith(str(p))


@pytest.mark.parametrize(
    "name, data, match",
    [
        ("x.op4", b"\x00\x01garbage" * 20, "not a readable OP4"),
        ("x.op4", b"this is not an op4 file\n", "not a readable OP4"),
        ("x.mat", b"not a mat file at all", "not a readable MATLAB"),
        ("x.txt", b"1 2 3", "not a recognised matrix file"),
        ("x.h5", b"\x89HDF\r\n\x1a\n" + b"\x00" * 64, "HDF5"),
    ],
)
def test_unreadable_files(tmp_path, name, data, match):
    p = tmp_path / name
    p.write_bytes(data)
    with pytest.raises(InputError, match=match) as exc:
        read_analysis_model(p)
    assert "\n" not in str(exc.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_analysis_model(tmp_path / "none.op4")
    with pytest.raises(InputError, match="not a file"):
        read_analysis_model(tmp_path)
