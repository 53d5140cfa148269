"""UFF units: the axis unit labels and exponents of dataset 58 records 8-10, with and without a
dataset 164 (ssid.exchange.uff_units; rules in docs/exchange.md, "Units of other programs")."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from conftest import chain_frf
from test_uff import commercial_file, fortran, header58, rows

from ssid.errors import InputError
from ssid.exchange import UFFWarning, read_uff_frf, write_uff_frf
from ssid.exchange._uffio import write_datasets
from ssid.exchange.uff import frf_datasets
from ssid.exchange.uff_units import normalise_label

pytest.importorskip("pyuff")

G, IN, LBF = 9.80665, 0.0254, 4.4482216152605  # exact definitions (m/s^2, m, N)
# Binary 58b holds float64: a value divided by a unit factor on writing and multiplied by it on
# reading is back within a few ulp.
SCALED_RTOL = 1e-14


def labelled_file(path, frf, *, ordinate=None, denominator=None, abscissa=None, scale=1.0,
                  x_scale=1.0, units_164=True, length=1.0, edit=None):
    """Write ``frf`` as binary 58b (pyuff) with the FRFs' values divided by ``scale`` and their
    abscissae multiplied by ``x_scale``, the given unit labels, and with or without a dataset
    164 (ssidlab's SI one, or with the length factor ``length``); ``edit(d)`` may change each
    FRF's dictionary further."""
    datasets = frf_datasets(str(path), frf, binary=True)
    if units_164:
        datasets[0]["length"] = length
    else:
        datasets = [d for d in datasets if d["type"] != 164]
    for d in datasets:
        if d["type"] != 58 or d["func_type"] != 4:
            continue
        d["data"] = d["data"] / scale
        d["x"] = d["x"] * x_scale
        for key, label in (("ordinate", ordinate), ("orddenom", denominator),
                           ("abscissa", abscissa)):
            if label is not None:
                d[f"{key}_axis_units_lab"] = label
        if edit:
            edit(d)
    write_datasets(path, datasets)
    return path


def read_quietly(path):
    """Read, failing on any warning: recognised labels need none."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return read_uff_frf(path)


def messages(record) -> list[str]:
    return [str(w.message) for w in record]


@pytest.mark.parametrize("label, expected", [
    ("m/s^2", "m/s^2"), ("m/s2", "m/s^2"), ("M/S**2", "m/s^2"), ("m/s²", "m/s^2"),
    ("m/sec^2", "m/s^2"), ("m s^-2", "m/s^2"), ("m/s/s", "m/s^2"), ("[g]", "g"), ("G", "g"),
    ("in/sec2", "in/s^2"), ("N-m", "n*m"), ("N.m", "n*m"), ("°/s²", "deg/s^2"), ("µm", "um"),
])
def test_label_spellings_normalise(label, expected):
    assert normalise_label(label) == expected


@pytest.mark.parametrize("ordinate, denominator, factor", [
    ("g", "N", G),
    ("G", "N", G),
    ("g's", "lbf", G / LBF),
    ("m/s2", "N", 1.0),
    ("m/s**2", "kN", 1e-3),
    ("mm/s^2", "N", 1e-3),
    ("in/s^2", "lbf", IN / LBF),
    ("in/sec^2", "LBF", IN / LBF),
])
def test_labelled_units_without_a_164_are_converted_to_si(tmp_path, ordinate, denominator,
                                                            factor):
    """The common lab file: no dataset 164, FRFs in g per N. It was read as (m/s^2)/N, a
    silent factor 9.81 (QA)."""
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "lab.uff", frf, ordinate=ordinate, denominator=denominator,
                         scale=factor, units_164=False)
    back = read_quietly(path)
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL, atol=0)


def test_a_hand_written_file_in_us_units(tmp_path):
    """Hand-written ASCII (single precision E13.5 and double D20.12), no 164: an accelerance
    in g/lbf and a mobility in in/s per lbf. Values are compared with the numbers as written,
    so only the conversion's rounding (a few ulp) remains."""
    text, expected = commercial_file(units_164=False, acc_units=("g", "lbf"),
                                     mob_units=("in/s", "lbf"))
    path = tmp_path / "us.unv"
    path.write_bytes(text.encode("ascii"))
    with pytest.warns(UFFWarning, match="0 Hz") as record:
        frf = read_uff_frf(path)
    assert len(record) == 1  # the DC line only: the labels are all known
    f = expected["freq"][1:]
    np.testing.assert_allclose(frf.H[:, 0, 0], expected["acc"][1:] * G / LBF, rtol=1e-15)
    np.testing.assert_allclose(frf.H[:, 1, 0], 1j * 2 * np.pi * f * expected["mob"][1:] * IN / LBF,
                               rtol=1e-14)


@pytest.mark.parametrize("label, per_hz", [("rad/s", 2 * math.pi), ("RPM", 60.0), ("kHz", 1e-3),
                                            ("Hz", 1.0)])
def test_an_abscissa_not_in_hz_is_converted(tmp_path, label, per_hz):
    """The abscissa in rad/s (or rpm, kHz) is converted before a mobility's j omega, so the
    accelerance is right too."""
    frf = chain_frf(n_freq=8)

    def mobility(d):
        d["ordinate_spec_data_type"] = 11
        d["data"] = d["data"] / (1j * 2 * np.pi * d["x"] / per_hz)

    path = labelled_file(tmp_path / "w.uff", frf, ordinate="mm/s", abscissa=label,
                         scale=1e-3, x_scale=per_hz, units_164=False, edit=mobility)
    back = read_quietly(path)
    np.testing.assert_allclose(back.freq_hz, frf.freq_hz, rtol=1e-15)
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL)


def test_an_untyped_ordinate_is_what_its_label_says(tmp_path):
    """Specific data types 0 (unknown) with labels mm/s per N: a mobility, converted with
    j omega and 1e-3, without the "do not say" warning; before, it was taken as an
    accelerance (with that warning)."""
    frf = chain_frf(n_freq=8)

    def untyped_mobility(d):
        d["ordinate_spec_data_type"] = d["orddenom_spec_data_type"] = 0
        d["data"] = d["data"] / (1j * 2 * np.pi * d["x"])  # v = a / (j omega)

    path = labelled_file(tmp_path / "u.uff", frf, ordinate="mm/s", denominator="N", scale=1e-3,
                         units_164=False, edit=untyped_mobility)
    back = read_quietly(path)
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL)


def test_a_164_and_labels_that_agree_convert_once(tmp_path):
    """Dataset 164 in mm and labels mm/s^2 say the same: the values are divided by 1000 once,
    not twice, and there is nothing to warn about."""
    text, expected = commercial_file()  # 164 in mm; labels mm/s^2, mm/s per N
    path = tmp_path / "mm.unv"
    path.write_bytes(text.encode("ascii"))
    with pytest.warns(UFFWarning) as record:
        frf = read_uff_frf(path)
    assert messages(record) == [m for m in messages(record) if "0 Hz" in m]
    np.testing.assert_allclose(frf.H[:, 0, 0], expected["acc"][1:] / 1000, rtol=1e-15)


def test_a_label_that_disagrees_with_the_164_wins_with_one_warning(tmp_path):
    """Dataset 164 says SI, every FRF's label says g: the values are g (labels are per
    function and set by the acquisition channel; a 164 is often boilerplate), and one warning
    names the disagreement."""
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "g164.uff", frf, ordinate="g", scale=G)
    with pytest.warns(UFFWarning) as record:
        back = read_uff_frf(path)
    found = [m for m in messages(record) if "disagree with dataset 164" in m]
    assert len(found) == 1 and "'g'" in found[0] and "labels were followed" in found[0]
    assert f"{frf.n_out * frf.n_in} axis unit label(s)" in found[0]
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL)


def test_a_scalar_dof_labelled_as_a_rotation_agrees_with_a_164(tmp_path):
    """164 in mm: a scalar output labelled rad/s^2 is an angular acceleration, which the 164
    leaves alone, so it agrees; the translations labelled mm/s^2 agree too. No warning."""
    frf = chain_frf(n_freq=8)
    frf.outputs = ["1+Z", "2+Z", "30"]
    frf.inputs = ["1+Z", "2+Z"]

    def label(d):
        scalar = d["rsp_dir"] == 0
        d["ordinate_axis_units_lab"] = "rad/s^2" if scalar else "mm/s^2"
        d["data"] = d["data"] * (1.0 if scalar else 1e3)

    back = read_quietly(labelled_file(tmp_path / "s.uff", frf, length=1e3, edit=label))
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL)


def test_an_unrecognised_frf_label_is_refused(tmp_path):
    """An FRF labelled in a unit nobody can convert was read as SI behind a warning: a wrong
    scale that the FRF file then carries silently (QA). It is refused, saying how to fix it."""
    frf = chain_frf(n_freq=8)
    for edit, said in (({"ordinate_axis_units_lab": "furlong/fortnight^2"},
                        "ordinate unit label 'furlong/fortnight^2'"),
                       ({"orddenom_axis_units_lab": "stone"}, "denominator unit label 'stone'")):
        path = labelled_file(tmp_path / "odd.uff", frf, edit=lambda d, e=edit: d.update(e))
        with pytest.raises(InputError) as exc:
            read_uff_frf(path)
        message = str(exc.value)
        assert f"dataset 2 (58): {said} is not a unit ssidlab knows" in message
        assert "or to NONE" in message and "dataset 164" in message and "\n" not in message


def test_an_unrecognised_abscissa_label_is_reported_once_and_read_in_hz(tmp_path):
    """A frequency's unit does not depend on the 164: an unknown abscissa label stays one
    warning per file, the abscissa read in Hz."""
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "odd.uff", frf, abscissa="cycles per second")
    with pytest.warns(UFFWarning) as record:
        back = read_uff_frf(path)
    assert messages(record) == [(f"{path}: abscissa unit label(s) 'cycles per second' not "
                                 "recognised (first in dataset 2); read as frequency in Hz")]
    np.testing.assert_array_equal(back.H, frf.H)


def mobility(d):
    """Make an FRF dictionary of labelled_file a mobility (ordinate velocity, v = a / j omega)."""
    d["ordinate_spec_data_type"] = 11
    d["data"] = d["data"] / (1j * 2 * np.pi * d["x"])


@pytest.mark.parametrize("ordinate, denominator, factor, edit", [
    ("Gs/N", "NONE", G, None),  # ME'scope's accelerance label
    ("g/lbf", "NONE", G / LBF, None),
    ("G/N", "N", G, None),  # the denominator label agrees: converted once
    ("(m/s^2)/N", "NONE", 1.0, None),
    ("in/s^2/lbf", "", IN / LBF, None),
    ("mm/s/N", "NONE", 1e-3, mobility),
    ("mg/N", "NONE", 1e-3 * G, None),
])
def test_an_ordinate_label_carrying_the_whole_frf_unit(tmp_path, ordinate, denominator, factor,
                                                        edit):
    """'Gs/N' on the ordinate, NONE on the denominator, values in g per N: both units apply.
    It was an unrecognised label read as SI with a warning, H off by 9.81 (QA)."""
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "ratio.uff", frf, ordinate=ordinate, denominator=denominator,
                         scale=factor, units_164=False, edit=edit)
    back = read_quietly(path)
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL, atol=0)


def test_a_ratio_label_is_checked_against_the_164_part_by_part(tmp_path):
    """With an SI 164 each part of 'g/lbf' disagrees: the labels win, one warning names the
    first part and its label."""
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "ratio.uff", frf, ordinate="g/lbf", denominator="NONE",
                         scale=G / LBF)
    with pytest.warns(UFFWarning) as record:
        back = read_uff_frf(path)
    assert len(record) == 1
    assert f"{2 * frf.n_out * frf.n_in} axis unit label(s) disagree" in messages(record)[0]
    assert "'g' (of 'g/lbf') in dataset 2 (58)" in messages(record)[0]
    np.testing.assert_allclose(back.H, frf.H, rtol=SCALED_RTOL)


@pytest.mark.parametrize("ordinate, denominator, expected", [
    ("mm/s/N", "NONE", ("ordinate unit 'mm/s' (of 'mm/s/N') is a velocity unit, but the "
                        "ordinate is acceleration")),
    ("g/g", "NONE", ("denominator unit 'g' (of 'g/g') is an acceleration unit, but the "
                     "denominator is excitation force")),
    ("g/N", "lbf", ("ordinate unit label 'g/N' gives the denominator's unit ('N'), but the "
                    "denominator label is 'lbf'")),
    ("g/N*m", "NONE", ("denominator unit 'N*m' (of 'g/N*m') is a moment unit, but 1+Z is a "
                       "translation")),
])
def test_a_ratio_label_that_contradicts_the_function_is_refused(tmp_path, ordinate,
                                                                 denominator, expected):
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "bad.uff", frf, ordinate=ordinate, denominator=denominator)
    with pytest.raises(InputError) as exc:
        read_uff_frf(path)
    assert expected in str(exc.value) and "dataset 2 (58)" in str(exc.value)


def test_milli_g_is_a_thousandth_of_g(tmp_path):
    """'mg' on a motion axis is milli-g; it was an unrecognised label read as m/s^2 (x 102)."""
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "mg.uff", frf, ordinate="mg", scale=1e-3 * G,
                         units_164=False)
    np.testing.assert_allclose(read_quietly(path).H, frf.H, rtol=SCALED_RTOL)


def test_our_own_labels_read_back_exactly_and_quietly(tmp_path):
    """What write_uff_frf writes (m/s^2, rad/s^2 per N, N*m; reactions N; Hz) is read back
    bit for bit and without a warning."""
    frf = chain_frf(inputs=["1+Z"], n_freq=6)
    frf.outputs = ["1+Z", "2-RX", "30"]
    frf.inputs = ["1+Z"]
    frf.reactions = ["2-RX"]  # a reaction moment, N*m per N
    frf.H_reaction = frf.H[:, :1, :] * 3.0
    write_uff_frf(tmp_path / "own.uff", frf, binary=True)
    rotated = chain_frf(inputs=["1+Z"], n_freq=6)
    rotated.outputs, rotated.inputs = ["1+RZ", "2+Z", "3+Z"], ["1+RZ"]
    write_uff_frf(tmp_path / "moment.uff", rotated, binary=True)
    assert b"N*m" in (tmp_path / "moment.uff").read_bytes()
    for path, sent in ((tmp_path / "own.uff", frf), (tmp_path / "moment.uff", rotated)):
        back = read_quietly(path)
        np.testing.assert_array_equal(back.freq_hz, sent.freq_hz)
        np.testing.assert_array_equal(back.H, sent.H)
    np.testing.assert_array_equal(read_quietly(tmp_path / "own.uff").H_reaction, frf.H_reaction)


def test_exponents_give_a_scalar_dofs_164_units(tmp_path):
    """A scalar reference (direction 0) excited by a moment: its denominator exponents (length
    1, force 1) make the 164 factor length x force; unlabelled, zero exponents take it as a
    force (as before)."""
    values = [complex(0.5, -0.25), complex(1.5, 0.75), complex(-2.0, 0.125)]  # exact in E13.5
    for name, exps in (("moment", ((0, 0), (1, 1))), ("force", ((0, 0), (0, 0)))):
        scalar = ("NONE", 9, 0)
        lines = ["    -1", "   164", f"{9:10d}{'mm N':<20s}{2:10d}",
                 "  0.10000000000000000D+04  0.10000000000000000D+01  0.10000000000000000D+01",
                 "  0.27314999389648438D+03", "    -1"]
        lines += header58("scalar", 4, scalar, scalar, 5, 3, 10.0, 5.0,
                          (12, "Acceleration", "NONE"), (13, name, "NONE"), exps=exps)
        lines += rows([fortran(p) for z in values for p in (z.real, z.imag)], 6) + ["    -1"]
        (tmp_path / f"{name}.unv").write_text("\n".join(lines) + "\n")
    moment, force = (read_quietly(tmp_path / f"{k}.unv").H[:, 0, 0] for k in ("moment", "force"))
    # mm N units: (mm/s^2)/(N mm) -> x 1000 / 1000; (mm/s^2)/N -> / 1000.
    np.testing.assert_allclose(moment, values, rtol=1e-15)
    np.testing.assert_allclose(force, np.array(values) / 1000, rtol=1e-15)


@pytest.mark.parametrize("edit, expected", [
    (dict(ordinate_axis_units_lab="mm/s"),
     "ordinate unit label 'mm/s' is a velocity unit, but the ordinate is acceleration"),
    (dict(orddenom_axis_units_lab="g", orddenom_spec_data_type=0),
     "denominator unit label 'g' is an acceleration unit, but the denominator is a force"),
    (dict(orddenom_axis_units_lab="N*m"),
     "denominator unit label 'N*m' is a moment unit, but 1+Z is a translation"),
    (dict(abscissa_axis_units_lab="s"), "abscissa unit label 's' is a time, not a frequency"),
    (dict(abscissa_axis_units_lab="Orders"), "is an order, not a frequency"),
])
def test_labels_that_contradict_their_axis_are_refused(tmp_path, edit, expected):
    frf = chain_frf(n_freq=8)
    path = labelled_file(tmp_path / "bad.uff", frf, edit=lambda d: d.update(edit))
    with pytest.raises(InputError) as exc:
        read_uff_frf(path)
    assert expected in str(exc.value) and "\n" not in str(exc.value)
    assert "dataset 2 (58)" in str(exc.value)


def test_a_translation_label_on_a_rotation_is_refused(tmp_path):
    frf = chain_frf(inputs=["1+Z"], n_freq=6)
    frf.outputs = ["1+Z", "2+RX", "3+Z"]
    frf.inputs = ["1+Z"]
    path = labelled_file(tmp_path / "rot.uff", frf, ordinate="g", units_164=False)
    with pytest.raises(InputError, match=r"dataset 2 \(58\): ordinate unit label 'g' is an "
                                         r"acceleration unit, but 2\+RX is a rotation"):
        read_uff_frf(path)
