"""Bad input files and option combinations: a one-line error and exit status 2, never a
traceback, an internal error or a file written from garbage.

Each test builds its input in ``tmp_path``; each failed before the fix it guards (named in
its docstring).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable

import h5py
import numpy as np
import pytest
import scipy.io
from conftest import chain_frf, chain_model, one_error_line

from ssid.errors import InputError
from ssid.exchange import modes_from_model, read_uff_frf, write_uff_frf
from ssid.frf import FRFData
from ssid.io import Model, write_frf, write_model
from ssid.matrix_io import read_analysis_model

pytest.importorskip("pyuff")


# ----------------------------------------------------------------------------------------------
# 1. convert: a result JSON that is not an object
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text, kind", [("[1, 2, 3]", "an array"), ("42", "a number"),
                                        ('"hello"', "a string")])
def test_convert_refuses_a_json_that_is_not_an_object(tmp_path, ssidlab, text, kind):
    """Was an internal error: AttributeError: 'list' object has no attribute 'mode_shapes'."""
    src = tmp_path / "r.json"
    src.write_text(text)
    status, _, err = ssidlab("convert", src, tmp_path / "x.uff")
    line = one_error_line(err, "convert")
    assert status == 2 and str(src) in line and "not an ssidlab result" in line and kind in line
    assert not (tmp_path / "x.uff").exists()


# ----------------------------------------------------------------------------------------------
# 2. MATLAB v7.3 files with damaged HDF5 structure
# ----------------------------------------------------------------------------------------------


def _mat73(path, extra) -> None:
    """A MATLAB -v7.3 file (512-byte user block with the MATLAB header) of the chain model,
    labels as a char matrix; ``extra(f)`` damages it."""
    m = chain_model()
    with h5py.File(path, "w", userblock_size=512) as f:
        f.create_dataset("M", data=m.M.T).attrs["MATLAB_class"] = np.bytes_("double")
        f.create_dataset("K", data=m.K.T).attrs["MATLAB_class"] = np.bytes_("double")
        # A 3 x 3 char matrix, one label per row; column-major, HDF5 sees one per column.
        codes = np.zeros((3, 3), dtype=np.uint16)
        for j, label in enumerate(m.dofs):
            codes[: len(label), j] = [ord(c) for c in label]
        f.create_dataset("dofs", data=codes).attrs["MATLAB_class"] = np.bytes_("char")
        extra(f)
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" "))


def _null_ref_cell(f) -> None:
    del f["dofs"]
    f.create_dataset("dofs", shape=(3, 1), dtype=h5py.ref_dtype).attrs["MATLAB_class"] = np.bytes_("cell")


@pytest.mark.parametrize("damage, match", [
    (lambda f: f.__setitem__("X", h5py.SoftLink("/nowhere")), r"soft link to '/nowhere'"),
    (lambda f: f.__setitem__("Y", h5py.ExternalLink("missing.h5", "/a")), r"external link .*missing\.h5"),
    (_null_ref_cell, r"cell 1 of 'dofs' holds a null reference"),
])
def test_damaged_mat73_is_input_error(tmp_path, damage, match):
    """Were AttributeError 'NoneType' ... attrs (dangling soft or external link) and
    ValueError Invalid HDF5 object reference (a cell of null references)."""
    p = tmp_path / "m73.mat"
    _mat73(tmp_path / "intact.mat", lambda f: None)
    assert read_analysis_model(tmp_path / "intact.mat").dofs == chain_model().dofs
    _mat73(p, damage)
    with pytest.raises(InputError, match=match) as exc:
        read_analysis_model(p)
    message = str(exc.value)
    assert message.startswith(f"{p}: damaged MATLAB v7.3 file (") and "\n" not in message


def test_damaged_mat73_on_the_command_line(tmp_path, ssidlab):
    p = tmp_path / "m73.mat"
    _mat73(p, lambda f: f.__setitem__("X", h5py.SoftLink("/nowhere")))
    status, _, err = ssidlab("place", p, "--sensors", "2", "--json", tmp_path / "x.json")
    assert status == 2 and "damaged MATLAB v7.3 file" in one_error_line(err, "place")


# ----------------------------------------------------------------------------------------------
# 3. convert: model and result -> UFF 55 with nothing physical to write
# ----------------------------------------------------------------------------------------------


def _model_file(tmp_path, **change) -> str:
    m = chain_model()
    path = tmp_path / "model.h5"
    write_model(path, Model(M=change.get("M", m.M), K=change.get("K", m.K), C=change.get("C", m.C),
                            dofs=m.dofs))
    return str(path)


@pytest.mark.parametrize("change, match", [
    ({"M": np.diag([1.0, -2.0, 1.5])}, r"M has the negative eigenvalue -2"),
    ({"M": np.diag([1.0, 0.0, 1.5])}, r"M is singular"),
    ({"M": np.zeros((3, 3))}, r"M is zero"),
    ({"K": np.zeros((3, 3))}, r"K is zero: the model has no elastic modes"),
    ({"K": np.zeros((3, 3)), "C": None}, r"K is zero: the model has no elastic modes"),
    ({"K": -chain_model().K}, r"K is not positive semi-definite"),
    ({"C": 1e6 * np.eye(3)}, r"no oscillating mode"),
])
def test_convert_refuses_a_model_without_modes(tmp_path, ssidlab, change, match):
    """A negative-definite M and an unstable K were written (exit 0); a zero K gave "mode
    shapes (3, 0) must be ... = (3, 0)"; a singular M "model: cannot compute ..." without
    the file's name."""
    src = _model_file(tmp_path, **change)
    status, _, err = ssidlab("convert", src, tmp_path / "x.uff")
    line = one_error_line(err, "convert")
    assert status == 2 and line.startswith(f"ssidlab convert: error: {src}: ") and re.search(match, line), line
    assert not (tmp_path / "x.uff").exists()


def test_free_free_model_keeps_its_rigid_body_modes():
    """Round-off on a rigid-body mode is 0 Hz, not a negative frequency (which the writer now
    refuses) nor an unstable K."""
    m = chain_model()
    K = m.K.copy()
    K[0, 0] -= 1e4  # the chain's ground spring removed: one rigid-body mode
    modes = modes_from_model(m.M, None, K, m.dofs)
    assert modes.natural_freq_hz[0] == pytest.approx(0.0, abs=1e-6) and np.all(modes.natural_freq_hz >= 0)


def _result(freq, shapes) -> dict:
    shapes = np.asarray(shapes, dtype=complex)
    return {"natural_freq_hz": list(freq), "damping_ratio": [0.01] * len(freq), "dofs": chain_model().dofs,
            "mode_shapes": {"dofs": chain_model().dofs, "real": shapes.real.tolist(), "imag": shapes.imag.tolist()}}


@pytest.mark.parametrize("freq, zero_column, match", [
    ([-5.0, 12.0], None, r"mode 1 has the frequency -5 Hz; a mode's natural frequency must be positive"),
    ([5.0, 12.0], 1, r"the shape of mode 2 is zero at every DOF"),
    ([1e308, 12.0], None, r"mode 1 has the frequency 1e\+308 Hz, too large"),
])
def test_convert_refuses_a_result_with_garbage_modes(tmp_path, ssidlab, freq, zero_column, match):
    """Negative frequencies and all-zero shapes were written without a word (exit 0)."""
    shapes = np.array([[1.0, 0.5], [0.5, -1.0], [0.2, 0.3]])
    if zero_column is not None:
        shapes[:, zero_column] = 0.0
    src = tmp_path / "result.json"
    src.write_text(json.dumps(_result(freq, shapes)))
    status, _, err = ssidlab("convert", src, tmp_path / "x.uff")
    line = one_error_line(err, "convert")
    assert status == 2 and f"{src}: " in line and re.search(match, line), line


# ----------------------------------------------------------------------------------------------
# 4. FRF -> UFF 58 with 4+Z and 4-Z both among the outputs
# ----------------------------------------------------------------------------------------------


def _opposite_outputs_frf() -> FRFData:
    base = chain_frf(inputs=["1+Z"])
    H = base.H[:, :2, :].copy()
    H[:, 1, :] *= -1.0  # the same DOF, measured in the other sense
    return FRFData(freq_hz=base.freq_hz, H=H, outputs=["1+Z", "1-Z"], inputs=["1+Z"])


def test_uff_writer_refuses_one_dof_in_both_senses(tmp_path, ssidlab):
    """Was written (exit 0) as a file ssidlab's own reader refused ("datasets 2 and 3 are
    both the FRF 1+Z/1+Z"): in UFF 58 the sign is only the measuring sense of one DOF."""
    with pytest.raises(InputError, match=r"outputs '1\+Z' and '1-Z' are the same DOF in UFF 58"):
        write_uff_frf(tmp_path / "x.uff", _opposite_outputs_frf())
    write_frf(tmp_path / "frf.h5", _opposite_outputs_frf())
    status, _, err = ssidlab("convert", tmp_path / "frf.h5", tmp_path / "y.uff")
    assert status == 2 and "'1+Z' and '1-Z'" in one_error_line(err, "convert")
    assert not (tmp_path / "y.uff").exists()


# ----------------------------------------------------------------------------------------------
# 5. Infinite values in an ASCII UFF 58
# ----------------------------------------------------------------------------------------------


def _uff_with_value(path, text: Callable[[str], str]) -> int:
    """An ASCII UFF 58 of one input whose 4th value of the first FRF has the real part
    ``text(field)`` (of the field's width: the columns are fixed); returns that line's number
    (from 1)."""
    write_uff_frf(path, chain_frf(inputs=["1+Z"], n_freq=8))
    lines = path.read_text().splitlines()
    start = [k for k, line in enumerate(lines) if line.strip() == "-1"][2]  # dataset 2, after the 164
    k = start + 13 + 3  # -1, "58", 11 header records; uneven complex double: one value per line
    _, re_part, _ = lines[k].split()
    lines[k] = lines[k].replace(re_part, text(re_part))
    path.write_text("\n".join(lines) + "\n")
    return k + 1


def _huge(field: str) -> str:
    sign = "-" if field.startswith("-") else ""
    return sign + "1." + "0" * (len(field) - len(sign) - 7) + "e+999"  # the same width


def test_uff_value_beyond_float64_is_refused_with_its_line(tmp_path, ssidlab):
    """``1e+999`` was read as inf and stored as a blanked value (inf+nanj), exit 0. A NaN is
    still a blanked value."""
    _uff_with_value(tmp_path / "nan.uff", lambda field: "NaN".rjust(len(field)))
    blanked = read_uff_frf(tmp_path / "nan.uff").valid
    assert blanked is not None and int((~blanked).sum()) == 1
    src = tmp_path / "frf.uff"
    k = _uff_with_value(src, _huge) - 1
    with pytest.raises(InputError, match=rf"dataset 2 \(58\): value 4 of 1\+Z/1\+Z .*line {k + 1}\) is infinite"):
        read_uff_frf(src)
    status, _, err = ssidlab("convert", src, tmp_path / "back.h5")
    assert status == 2 and "is infinite" in one_error_line(err, "convert")
    assert not (tmp_path / "back.h5").exists()


# ----------------------------------------------------------------------------------------------
# 6. An empty DOF label in a .mat cell array
# ----------------------------------------------------------------------------------------------


def test_mat_cell_with_an_empty_label_is_refused(tmp_path):
    """Was accepted: the model had a DOF labelled ""."""
    m = chain_model()
    p = tmp_path / "m.mat"
    scipy.io.savemat(p, {"M": m.M, "K": m.K, "dofs": np.array(["1+Z", "", "3+Z"], dtype=object)})
    with pytest.raises(InputError, match=r"dofs: label 2 of 3 is empty") as exc:
        read_analysis_model(p)
    assert str(exc.value).startswith(f"{p}: ")


# ----------------------------------------------------------------------------------------------
# 7. sim-model checks [sim] as check and acquire do
# ----------------------------------------------------------------------------------------------


def _sim_setup(tmp_path, old: str, new: str) -> str:
    from daq.simlab import example_setup_text

    text = example_setup_text()
    assert old in text
    path = tmp_path / "setup.toml"
    path.write_text(text.replace(old, new, 1))
    return str(path)


@pytest.mark.parametrize("old, new, match", [
    ('type = "added_mass"', 'type = "magic"', r"\[\[sim.effects\]\] #1 type: must be one of"),
    ("mass_kg = 0.25", "mass_kg = inf", r"\[\[sim.effects\]\] #1 mass_kg: must be a finite number, got inf"),
    ("stand_mass_kg = 20.0", "stand_mass_kg = inf", r"\[sim.stand\] stand_mass_kg: must be a finite number"),
])
def test_sim_model_validates_the_sim_tables(tmp_path, ssidlab, old, new, match):
    """``type = "magic"`` gave a model (exit 0); ``inf`` a "defective state matrix" or
    "Array must not contain infs" naming no key."""
    setup = _sim_setup(tmp_path, old, new)
    status, _, err = ssidlab("sim-model", setup, "--out", tmp_path / "model.h5")
    line = one_error_line(err, "sim-model")
    assert status == 2 and f"{setup}: " in line and re.search(match, line), line
    assert not (tmp_path / "model.h5").exists()


def test_sim_model_of_a_setup_without_a_sim_table_says_it_has_none(tmp_path, ssidlab):
    """Said only "[sim]: shaker at unknown DOF '16+Z'" (QA): the defaults' 14-DOF example
    structure was not named."""
    from daq.simlab import example_setup_text

    text = example_setup_text()
    setup = tmp_path / "setup.toml"
    setup.write_text(text[:text.index("[sim]")])
    status, _, err = ssidlab("sim-model", setup, "--out", tmp_path / "model.h5")
    line = one_error_line(err, "sim-model")
    assert status == 2 and "the setup has no [sim] table" in line and "structure = \"payload\"" in line, line


# ----------------------------------------------------------------------------------------------
# 8. discrepancy: options that would be ignored
# ----------------------------------------------------------------------------------------------


def test_discrepancy_refuses_two_effects_without_the_second_round(tmp_path, ssidlab):
    status, _, err = ssidlab("discrepancy", "--model", tmp_path / "m.h5", "--measured", tmp_path / "f.h5",
                             "--json", tmp_path / "d.json", "--max-effects", "2", "--no-second-round")
    line = one_error_line(err, "discrepancy")
    assert status == 2 and "--max-effects 2" in line and "--no-second-round" in line


def test_discrepancy_refuses_reactions_apply_without_reactions(tmp_path, ssidlab):
    write_model(tmp_path / "m.h5", chain_model())
    write_frf(tmp_path / "f.h5", chain_frf())
    status, _, err = ssidlab("discrepancy", "--model", tmp_path / "m.h5", "--measured", tmp_path / "f.h5",
                             "--json", tmp_path / "d.json", "--reactions", "apply")
    line = one_error_line(err, "discrepancy")
    assert status == 2 and f"{tmp_path / 'f.h5'}: --reactions apply" in line and "has none" in line
    assert not (tmp_path / "d.json").exists()


# ----------------------------------------------------------------------------------------------
# 9. HDF5 files damaged inside their metadata
# ----------------------------------------------------------------------------------------------


def _damaged_copy(src, dst, at: bytes, offset: int, new: bytes):
    """``src`` with ``new`` written ``offset`` bytes after the first ``at`` in it."""
    data = bytearray(src.read_bytes())
    i = data.find(at)
    assert i >= 0, f"no {at!r} in {src}"
    data[i + offset:i + offset + len(new)] = new
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("command, kind, at, offset, new", [
    # a group's B-tree signature overwritten: h5py raises RuntimeError ("wrong B-tree signature")
    ("identify", "frf", b"TREE", 0, b"XXXX"),
    ("convert", "frf", b"TREE", 0, b"XXXX"),
    # the byte before the root attribute's name: "ran off end of input buffer", a RuntimeError
    ("export-model", "model", b"format", -3, b"\xa2"),
    ("convert", "model", b"format", -3, b"\xa2"),  # said "HDF5 file of format ''"
    # the root group's index damaged: h5py's get() said the datasets were absent ("missing
    # dataset /M"), which reads as a file of the wrong kind
    ("export-model", "model", b"TREE", 0, b"XXXX"),
    ("export-model", "model", b"HEAP", 0, b"XXXX"),
    ("export-model", "model", b"SNOD", 0, b"XXXX"),
])
def test_damaged_hdf5_metadata_is_a_one_line_error(tmp_path, ssidlab, command, kind, at, offset, new):
    """Was an internal error (exit 1): RuntimeError from h5py, which only OSError was turned
    into "damaged HDF5 file" for."""
    good = tmp_path / "good.h5"
    if kind == "frf":
        write_frf(good, chain_frf())
    else:
        write_model(good, chain_model())
    bad = _damaged_copy(good, tmp_path / "bad.h5", at, offset, new)
    args = {"identify": ("identify", bad, "--out", tmp_path / "m.h5", "--json", tmp_path / "r.json"),
            "convert": ("convert", bad, tmp_path / "x.uff"),
            "export-model": ("export-model", bad, tmp_path / "x.mat")}[command]
    status, _, err = ssidlab(*args)
    line = one_error_line(err, command)
    assert status == 2 and f"{bad}: damaged HDF5 file" in line, line


def test_a_file_another_process_writes_is_read_not_called_damaged(tmp_path):
    """A running acquisition holds its run file for writing, and HDF5's lock refused every
    reader: `read_frf`, `convert`, `compare` said "damaged HDF5 file (unable to lock file)",
    of a good file that docs/acquisition.md says is readable during the run."""
    import subprocess
    import sys

    path = tmp_path / "frf.h5"
    write_frf(path, chain_frf())
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, h5py; f = h5py.File(sys.argv[1], 'r+'); print('open', flush=True); "
         "sys.stdin.read()", str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        with pytest.raises(OSError, match="unable to lock file"):  # what a reader meets
            h5py.File(path, "r")
        from ssid.io import read_frf

        assert np.array_equal(read_frf(path).H, chain_frf().H)
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
