"""UFF exchange: DOF labels, FRF round trips (ASCII 58, binary 58b), files in other programs'
conventions, malformed files. Mode shapes and geometry: tests/test_uff_modes.py."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import chain_frf, full_frf

from ssid.errors import InputError
from ssid.exchange import (
    UFFWarning,
    format_dof_label,
    parse_dof_label,
    read_uff_frf,
    read_uff_geometry,
    write_uff_frf,
)
from ssid.exchange._uffio import write_datasets
from ssid.exchange.uff import frf_datasets

pytest.importorskip("pyuff")

# ASCII 58 as written: values %20.11e = 12 significant digits -> relative error <= 5e-12 per
# real/imaginary part; the abscissa is E13.5 (the standard's record 12 format for uneven data)
# = 6 significant digits -> relative error <= 5e-6.
ASCII_VALUE_RTOL = 5e-12
ASCII_FREQ_RTOL = 5e-6


def one_line(exc: pytest.ExceptionInfo) -> str:
    message = str(exc.value)
    assert "\n" not in message
    return message


# ----------------------------------------------------------------------------------------------
# Labels
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("label, node_dir", [("4+Z", (4, 3)), ("17+RX", (17, 4)),
                                             ("2-Y", (2, -2)), ("9", (9, 0)),
                                             ("123456-RZ", (123456, -6))])
def test_label_round_trip(label, node_dir):
    assert parse_dof_label(label) == node_dir
    assert format_dof_label(*node_dir) == label


@pytest.mark.parametrize("label", ["acc1", "4+z", "04+Z", "4 +Z", "0+Z", "4+TX", "", "4+"])
def test_label_without_node_direction_form_is_refused(label):
    with pytest.raises(ValueError, match="not of the form"):
        parse_dof_label(label)


def test_write_refuses_labels_that_uff_cannot_address(tmp_path):
    frf = chain_frf()
    frf.outputs = ["base", "2+Z", "3+Z"]
    frf.inputs = ["base", "3+Z"]
    with pytest.raises(InputError) as exc:
        write_uff_frf(tmp_path / "x.uff", frf)
    assert "'base'" in one_line(exc) and "node" in one_line(exc)
    assert not (tmp_path / "x.uff").exists()


# ----------------------------------------------------------------------------------------------
# FRF round trips
# ----------------------------------------------------------------------------------------------


def _check_same_layout(back, frf):
    assert back.outputs == frf.outputs and back.inputs == frf.inputs
    assert back.reactions == frf.reactions
    np.testing.assert_array_equal(back.valid, frf.valid)
    assert np.all(np.isnan(back.H[~frf.valid]))  # blanked values come back blanked


def test_ascii_round_trip_within_format_precision(tmp_path):
    frf = full_frf()  # coherence, a blanked value, reactions
    path = tmp_path / "frf.uff"
    write_uff_frf(path, frf)
    back = read_uff_frf(path)
    _check_same_layout(back, frf)
    np.testing.assert_allclose(back.freq_hz, frf.freq_hz, rtol=ASCII_FREQ_RTOL, atol=0)
    ok = frf.valid
    for part in (np.real, np.imag):
        np.testing.assert_allclose(part(back.H[ok]), part(frf.H[ok]), rtol=ASCII_VALUE_RTOL, atol=0)
        np.testing.assert_allclose(part(back.H_reaction), part(frf.H_reaction),
                                   rtol=ASCII_VALUE_RTOL, atol=0)
    np.testing.assert_allclose(back.coherence, frf.coherence, rtol=ASCII_VALUE_RTOL, atol=0)
    # What dataset 58 cannot hold does not come back.
    assert back.H_var is None and back.n_avg is None and "operator" not in back.attrs


def test_binary_round_trip_is_exact(tmp_path):
    frf = full_frf()
    path = tmp_path / "frf.uff"
    write_uff_frf(path, frf, binary=True)
    back = read_uff_frf(path)
    _check_same_layout(back, frf)
    np.testing.assert_array_equal(back.freq_hz, frf.freq_hz)
    np.testing.assert_array_equal(back.H[frf.valid], frf.H[frf.valid])
    np.testing.assert_array_equal(back.coherence, frf.coherence)
    np.testing.assert_array_equal(back.H_reaction, frf.H_reaction)


def test_binary_header_byte_count_matches_the_data(tmp_path):
    frf = chain_frf(inputs=["1+Z"], n_freq=10)
    path = tmp_path / "frf.uff"
    write_uff_frf(path, frf, binary=True)
    raw = path.read_bytes()
    headers = re.findall(rb"\n    58b.{6}.{6}.{12}(.{12})", raw)
    assert len(headers) == 3
    # Uneven abscissa, complex double: frequency, real, imaginary per line.
    assert all(int(h) == 10 * 3 * 8 for h in headers)


def test_blanked_values_are_not_written_and_come_back_blanked(tmp_path):
    frf = chain_frf(n_freq=12)
    frf.valid = np.ones(frf.H.shape, dtype=bool)
    frf.valid[:, 2, 1] = False  # a whole FRF missing
    frf.valid[3, 0, 0] = False  # one value, its H left as a number
    path = tmp_path / "frf.uff"
    assert write_uff_frf(path, frf, binary=True) == frf.n_out * frf.n_in - 1
    assert path.read_text(errors="replace").count("    58b") == 5
    back = read_uff_frf(path)
    np.testing.assert_array_equal(back.valid, frf.valid)
    np.testing.assert_array_equal(back.H[frf.valid], frf.H[frf.valid])


def test_a_record_blanked_throughout_is_refused_not_written_empty(tmp_path):
    # Before: a file of coherence and reactions only, which the reader refuses ("no FRF"),
    # and the command said it had written every FRF.
    frf = chain_frf(n_freq=12)
    frf.coherence = np.full(frf.H.shape, 0.9)
    frf.valid = np.zeros(frf.H.shape, dtype=bool)
    with pytest.raises(InputError, match="no FRF has two valid lines"):
        write_uff_frf(tmp_path / "x.uff", frf)
    assert not (tmp_path / "x.uff").exists()


def test_a_line_blanked_everywhere_is_lost_without_coherence(tmp_path):
    frf = chain_frf(n_freq=12)
    frf.valid = np.ones(frf.H.shape, dtype=bool)
    frf.valid[4] = False
    write_uff_frf(tmp_path / "a.uff", frf, binary=True)
    back = read_uff_frf(tmp_path / "a.uff")
    np.testing.assert_array_equal(back.freq_hz, np.delete(frf.freq_hz, 4))
    assert back.valid is None
    # With coherence (written for every line) the line stays, blanked.
    frf.coherence = np.full(frf.H.shape, 0.9)
    write_uff_frf(tmp_path / "b.uff", frf, binary=True)
    back = read_uff_frf(tmp_path / "b.uff")
    np.testing.assert_array_equal(back.freq_hz, frf.freq_hz)
    np.testing.assert_array_equal(back.valid, frf.valid)


def test_single_valid_line_warns(tmp_path):
    frf = chain_frf(n_freq=8)
    frf.valid = np.ones(frf.H.shape, dtype=bool)
    frf.valid[1:, 1, 0] = False
    with pytest.warns(UFFWarning, match="single valid line"):
        write_uff_frf(tmp_path / "x.uff", frf)
    assert not read_uff_frf(tmp_path / "x.uff").valid[:, 1, 0].any()


def test_ascii_refuses_lines_its_abscissa_cannot_separate(tmp_path):
    frf = chain_frf(n_freq=4)
    frf.freq_hz = np.array([100.0, 100.0000001, 100.0000002, 100.0000003])
    with pytest.raises(InputError, match="binary 58b"):
        write_uff_frf(tmp_path / "x.uff", frf)
    write_uff_frf(tmp_path / "x.uff", frf, binary=True)
    np.testing.assert_array_equal(read_uff_frf(tmp_path / "x.uff").freq_hz, frf.freq_hz)


def test_rotational_and_negative_directions_round_trip(tmp_path):
    frf = chain_frf(inputs=["1+Z"], n_freq=6)
    frf.outputs = ["1+Z", "2-RX", "30"]
    frf.inputs = ["1+Z"]
    write_uff_frf(tmp_path / "x.uff", frf)
    text = (tmp_path / "x.uff").read_text()
    assert "rad/s^2" in text  # the rotational response is an angular acceleration
    assert read_uff_frf(tmp_path / "x.uff").outputs == ["1+Z", "2-RX", "30"]


# ----------------------------------------------------------------------------------------------
# Files in other programs' conventions
# ----------------------------------------------------------------------------------------------


def fortran(x: float, width: int = 13, digits: int = 5, letter: str = "E") -> str:
    """Fortran ``Ew.d`` / ``Dw.d`` output: ``0.12346E+01``, right-justified."""
    exp = 0 if x == 0 else int(np.floor(np.log10(abs(x)))) + 1
    mant = x / 10.0**exp
    if round(abs(mant), digits) >= 1.0:
        mant, exp = mant / 10, exp + 1
    return f"{mant:.{digits}f}{letter}{exp:+03d}".rjust(width)


def header58(id1: str, func: int, rsp: tuple, ref: tuple, ord_type: int, n: int, f0: float,
             df: float, num: tuple, den: tuple, abscissa: str = "Hz",
             exps: tuple = ((0, 0), (0, 0))) -> list[str]:
    return [
        "    -1", "    58", id1, "Run 12 hammer test", "12-MAR-24 10:11:12", "NONE", "NONE",
        (f"{func:5d}{1:10d}{1:5d}{0:10d} {rsp[0]:<10s}{rsp[1]:10d}{rsp[2]:4d} "
         f"{ref[0]:<10s}{ref[1]:10d}{ref[2]:4d}"),
        f"{ord_type:10d}{n:10d}{1:10d}{fortran(f0)}{fortran(df)}{fortran(0.0)}",
        f"{18:10d}{0:5d}{0:5d}{0:5d} {'Frequency':<20s} {abscissa:<20s}",
        f"{num[0]:10d}{exps[0][0]:5d}{exps[0][1]:5d}{0:5d} {num[1]:<20s} {num[2]:<20s}",
        f"{den[0]:10d}{exps[1][0]:5d}{exps[1][1]:5d}{0:5d} {den[1]:<20s} {den[2]:<20s}",
        f"{0:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}",
    ]


def rows(fields: list[str], per_line: int) -> list[str]:
    return ["".join(fields[k:k + per_line]) for k in range(0, len(fields), per_line)]


def commercial_file(acc_rsp=("PT1", 1, 3), mob_rsp=("PT2", 2, -2), ref=("PT1", 1, 3),
                    acc_den=13, acc_units=("mm/s^2", "N"), mob_units=("mm/s", "N"),
                    units_164=True) -> tuple[str, dict]:
    """A UFF in the style of a commercial test package: CRLF, Fortran 0.d exponents, D
    exponents, mm units (164), even abscissa, single and double precision, a 0 Hz line.
    Its accelerance's and mobility's response (name, node, direction), their reference, the
    accelerance's denominator type, the unit labels (ordinate, denominator) of both, and
    whether there is a dataset 164 can be changed."""
    rng = np.random.default_rng(3)
    f0, df, n = 0.0, 12.5, 5
    acc = rng.normal(size=n) + 1j * rng.normal(size=n)  # (mm/s^2)/N, single precision
    mob = rng.normal(size=n) + 1j * rng.normal(size=n)  # (mm/s)/N, double precision
    coh = rng.uniform(0.6, 0.99, size=(2, n))
    acc_txt = [fortran(v) for z in acc for v in (z.real, z.imag)]
    mob_txt = [fortran(v, 20, 12, "D") for z in mob for v in (z.real, z.imag)]
    lines = [
        "    -1", "   164", f"{9:10d}{'mm N s degC':<20s}{2:10d}",
        "  0.10000000000000000D+04  0.10000000000000000D+01  0.10000000000000000D+01",
        "  0.27314999389648438D+03", "    -1",
    ] if units_164 else []
    lines += [
        "    -1", "  2411",
        f"{1:10d}{0:10d}{0:10d}{11:10d}", "   0.0000000000000000D+00" * 3,
        f"{2:10d}{0:10d}{0:10d}{11:10d}",
        "   0.5000000000000000D+03   0.0000000000000000D+00   0.2500000000000000D+02",
        "    -1",
    ]
    lines += header58("PT1:+Z/PT1:+Z", 4, acc_rsp, ref, 5, n, f0, df,
                      (12, "Acceleration", acc_units[0]), (acc_den, "Force", acc_units[1]))
    lines += rows(acc_txt, 6) + ["    -1"]
    lines += header58("PT2:-Y/PT1:+Z", 4, mob_rsp, ref, 6, n, f0, df,
                      (11, "Velocity", mob_units[0]), (13, "Force", mob_units[1]))
    lines += rows(mob_txt, 4) + ["    -1"]
    for k, rsp in enumerate([acc_rsp, mob_rsp]):
        lines += header58("Multiple coherence", 26, rsp, ref, 2, n, f0, df,
                          (0, "Coherence", "NONE"), (0, "NONE", "NONE"))
        lines += rows([fortran(v) for v in coh[k]], 6) + ["    -1"]
    text = "\r\n".join(lines) + "\r\n"
    parsed = {
        "freq": f0 + df * np.arange(n),
        "acc": np.array([complex(float(a), float(b)) for a, b in zip(acc_txt[::2], acc_txt[1::2])]),
        "mob": np.array([complex(float(a.replace("D", "E")), float(b.replace("D", "E")))
                         for a, b in zip(mob_txt[::2], mob_txt[1::2])]),
        "coh": np.array([[float(fortran(v)) for v in c] for c in coh]),
    }
    return text, parsed


def test_reads_a_commercial_style_file(tmp_path):
    text, expected = commercial_file()
    path = tmp_path / "test_lab.unv"
    path.write_bytes(text.encode("ascii"))
    with pytest.warns(UFFWarning, match="0 Hz"):
        frf = read_uff_frf(path)
    assert frf.outputs == ["1+Z", "2-Y"] and frf.inputs == ["1+Z"]
    f = expected["freq"][1:]  # the 0 Hz line is dropped
    np.testing.assert_array_equal(frf.freq_hz, f)
    # mm -> m (164 length factor 1000); mobility -> accelerance with j omega.
    np.testing.assert_allclose(frf.H[:, 0, 0], expected["acc"][1:] / 1000, rtol=1e-15)
    np.testing.assert_allclose(frf.H[:, 1, 0], 1j * 2 * np.pi * f * expected["mob"][1:] / 1000,
                               rtol=1e-14)
    np.testing.assert_allclose(frf.coherence[:, :, 0], expected["coh"][:, 1:].T, rtol=1e-15)
    assert frf.valid is None
    geometry = read_uff_geometry(path)
    np.testing.assert_allclose(geometry[2], [0.5, 0.0, 0.025])


def test_unknown_ordinate_type_is_taken_as_accelerance_with_a_warning(tmp_path):
    text, expected = commercial_file(acc_units=("NONE", "N"))
    path = tmp_path / "x.uff"
    path.write_text(text.replace("        12    0    0    0 Acceleration",
                                 "         0    0    0    0 Acceleration"))
    with pytest.warns(UFFWarning) as record:
        frf = read_uff_frf(path)
    assert any("taken as acceleration" in str(w.message) for w in record)
    np.testing.assert_allclose(frf.H[:, 0, 0], expected["acc"][1:] / 1000, rtol=1e-15)


@pytest.mark.parametrize("mob_dir, ref_dir, acc_factor, mob_factor", [
    (4, 3, 1e-3, 1.0),  # 2+RX per force: (rad/s^2)/N takes no length factor
    (4, 4, 1e3, 1e3),  # per moment N*mm: (mm/s^2)/(N*mm) and (rad/s^2)/(N*mm)
])
def test_units_go_by_what_each_dof_is(tmp_path, mob_dir, ref_dir, acc_factor, mob_factor):
    """Dataset 164 in mm: a translation per force is divided by the length factor (1000), a
    rotation (radians) takes none, a moment (N mm) the force times the length factor. Every
    FRF was divided by 1000, whatever its DOFs (QA)."""
    rsp = ("PT1", 1, ref_dir)  # the accelerance is a driving point
    # Unlabelled axes: the units are dataset 164's, by what each DOF is.
    text, expected = commercial_file(acc_rsp=rsp, mob_rsp=("PT2", 2, mob_dir), ref=rsp,
                                     acc_units=("NONE", "NONE"), mob_units=("NONE", "NONE"))
    path = tmp_path / "rot.unv"
    path.write_bytes(text.encode("ascii"))
    with pytest.warns(UFFWarning, match="0 Hz"):
        frf = read_uff_frf(path)
    names = {3: "Z", 4: "RX"}
    assert frf.outputs == [f"1+{names[ref_dir]}", "2+RX"] and frf.inputs == [f"1+{names[ref_dir]}"]
    f = expected["freq"][1:]
    np.testing.assert_allclose(frf.H[:, 0, 0], expected["acc"][1:] * acc_factor, rtol=1e-14)
    np.testing.assert_allclose(frf.H[:, 1, 0], 1j * 2 * np.pi * f * expected["mob"][1:] * mob_factor,
                               rtol=1e-14)


def test_an_frf_not_per_force_is_refused_and_an_unknown_denominator_warned(tmp_path):
    """A transmissibility (acceleration per acceleration) was read as an accelerance without
    a word (QA)."""
    path = tmp_path / "t.uff"
    path.write_text(commercial_file(acc_den=12)[0])
    with pytest.raises(InputError, match=r"dataset 3 \(58\): FRF per acceleration; an FRF file holds "
                                         "responses per input force"):
        read_uff_frf(path)
    text, expected = commercial_file(acc_den=0, acc_units=("mm/s^2", "NONE"))
    path.write_text(text)
    with pytest.warns(UFFWarning) as record:
        frf = read_uff_frf(path)
    assert any("1 FRF(s) do not say what the ordinate or the denominator is" in str(w.message) for w in record)
    np.testing.assert_allclose(frf.H[:, 0, 0], expected["acc"][1:] / 1000, rtol=1e-15)


def test_one_dof_named_in_both_senses_is_one_dof(tmp_path):
    """An accelerometer mounted upside down at the driving point: response 1-Z per input
    1+Z. It was refused (the input not among the outputs); elsewhere one DOF became two
    outputs. The -Z function is folded onto 1+Z, its values negated; a -Y alone stays."""
    text, expected = commercial_file(acc_rsp=("PT1", 1, -3))
    path = tmp_path / "inverted.unv"
    path.write_bytes(text.encode("ascii"))
    with pytest.warns(UFFWarning, match="0 Hz"):
        frf = read_uff_frf(path)
    assert frf.outputs == ["1+Z", "2-Y"] and frf.inputs == ["1+Z"]
    np.testing.assert_allclose(frf.H[:, 0, 0], -expected["acc"][1:] / 1000, rtol=1e-15)
    np.testing.assert_allclose(frf.coherence[:, 0, 0], expected["coh"][0, 1:], rtol=1e-15)


def test_a_delimiter_with_trailing_blanks_loses_no_dataset(tmp_path):
    """pyuff takes "    -1" with trailing blanks for a delimiter only when they reach column
    80; one such line made it pair the others wrongly and drop two FRFs without a word (QA)."""
    frf = chain_frf(n_freq=8)
    path = tmp_path / "padded.uff"
    write_uff_frf(path, frf)
    lines = path.read_text().split("\n")
    k = [i for i, line in enumerate(lines) if line == "    -1"][3]  # the end of the first FRF
    lines[k] = "    -1  "
    path.write_text("\n".join(lines))
    back = read_uff_frf(path)
    assert back.outputs == frf.outputs and back.inputs == frf.inputs
    np.testing.assert_allclose(back.H, frf.H, rtol=1e-10)


# ----------------------------------------------------------------------------------------------
# Malformed files
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ascii_uff(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("uff") / "frf.uff"
    write_uff_frf(path, chain_frf(n_freq=8))
    return path


def _malformed(tmp_path: Path, text: str) -> str:
    path = tmp_path / "bad.uff"
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        read_uff_frf(path)
    return one_line(exc)


def test_malformed_files_give_one_line_errors(tmp_path, ascii_uff):
    text = ascii_uff.read_text()
    lines = text.splitlines()
    assert "no such file" in str(pytest.raises(InputError, read_uff_frf, tmp_path / "none.uff").value)
    assert "no datasets" in _malformed(tmp_path, "just some text\n1 2 3\n")
    assert "truncated" in _malformed(tmp_path, text[: len(text) // 2])
    first58 = lines.index("    58" + " " * 74)
    # A data line removed: fewer values than the header announces.
    assert "header announces" in _malformed(tmp_path, "\n".join(lines[:first58 + 14]
                                                               + lines[first58 + 15:]))
    # A number that is not one.
    broken = lines[:]
    broken[first58 + 13] = broken[first58 + 13].replace("e", "x", 1)
    assert "malformed" in _malformed(tmp_path, "\n".join(broken))
    # A direction code outside -6 .. 6.
    broken = lines[:]
    broken[first58 + 6] = broken[first58 + 6][:51] + "   9" + broken[first58 + 6][55:]
    assert "direction code 9" in _malformed(tmp_path, "\n".join(broken))
    # Functions, but none of them an FRF (function type 4 -> 2, auto spectrum).
    assert "no FRF" in _malformed(tmp_path, text.replace("\n    4 ", "\n    2 "))


def test_an_hdf5_file_is_not_a_uff(tmp_path):
    from ssid.io import write_frf

    write_frf(tmp_path / "frf.h5", chain_frf())
    with pytest.raises(InputError, match="HDF5"):
        read_uff_frf(tmp_path / "frf.h5")


def test_duplicate_functions_are_refused(tmp_path, ascii_uff):
    text = ascii_uff.read_text()
    blocks = text.split("    -1\n")
    dup = text + "    -1\n" + blocks[3] + "    -1\n"
    assert "both" in _malformed(tmp_path, dup)


def test_a_roving_hammer_file_is_refused_with_the_reciprocity_remedy(tmp_path):
    """One accelerometer (1+Z), the hammer at 1, 2, 3: the inputs are no outputs, which the
    FRF file refuses. The message said only "inputs label '2+Z' is not among outputs"; it
    now says why and that swapping response and reference (reciprocity) gives the layout,
    which then reads: the FRFs of a force at 1+Z."""
    frf = chain_frf(inputs=["1+Z", "2+Z", "3+Z"], n_freq=8)
    datasets = [d for d in frf_datasets("x", frf, binary=True)
                if d["type"] != 58 or (d["rsp_node"], d["rsp_dir"]) == (1, 3)]
    write_datasets(tmp_path / "roving.uff", datasets)
    with pytest.raises(InputError) as exc:
        read_uff_frf(tmp_path / "roving.uff")
    message = one_line(exc)
    assert "reference(s) '2+Z', '3+Z' of 3 are not among the 1 response(s)" in message
    assert "every input is an output" in message and "roving-hammer" in message
    assert "swap each dataset 58's response and reference" in message
    for d in datasets[1:]:
        d["rsp_node"], d["ref_node"] = d["ref_node"], d["rsp_node"]
    write_datasets(tmp_path / "swapped.uff", datasets)
    back = read_uff_frf(tmp_path / "swapped.uff")
    assert back.outputs == ["1+Z", "2+Z", "3+Z"] and back.inputs == ["1+Z"]
    np.testing.assert_array_equal(back.H[:, :, 0], frf.H[:, 0, :])


def test_an_input_that_is_not_measured_says_why_it_is_refused(tmp_path):
    frf = chain_frf(inputs=["1+Z"], n_freq=8)
    datasets = frf_datasets("x", frf, binary=True)
    for d in datasets[1:]:
        d["ref_node"] = 9
    write_datasets(tmp_path / "ref9.uff", datasets)
    with pytest.raises(InputError) as exc:
        read_uff_frf(tmp_path / "ref9.uff")
    message = one_line(exc)
    assert "reference(s) '9+Z' of 1 are not among the 3 response(s)" in message
    assert "roving-hammer" not in message
