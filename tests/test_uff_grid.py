"""The frequency grid of UFF files from other programs: lines that differ by the abscissa
format's rounding are one line; truly different grids are warned of (ssid.exchange.uff_grid,
docs/exchange.md "Frequency grid")."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import chain_model
from conftest import read_uff_with_warnings as read

from ssid.exchange._uffio import write_datasets
from ssid.exchange.uff import frf_datasets
from ssid.frf import accelerance_from_model

pytest.importorskip("pyuff")


def chain_on(freq):
    m = chain_model()
    return accelerance_from_model(m.M, m.C, m.K, m.dofs, freq, m.dofs, ["1+Z"])


def write(path, frf, even, binary=False):
    """``frf`` as UFF 58, the FRFs numbered in ``even`` written with an even abscissa
    (record 7's minimum and increment, E13.5), the others uneven (every value stored)."""
    datasets = frf_datasets(str(path), frf, binary=binary)
    functions = [d for d in datasets if d["type"] == 58]
    for k in even:
        functions[k]["abscissa_spacing"] = 1
    write_datasets(path, datasets)
    return path


@pytest.mark.parametrize("binary", [False, True])
def test_lines_that_differ_by_the_formats_rounding_are_one_line(tmp_path, binary):
    """Lines every 1/3 Hz: an even abscissa gives min + k * 3.33333e-01, an uneven ASCII one
    each line to 6 digits; they differ by about 1e-6 relative. They were 597 lines, each
    function blanked on the other's half, without a warning (QA)."""
    freq = np.arange(1, 301) / 3.0
    frf = chain_on(freq)
    back, found = read(write(tmp_path / "third.uff", frf, even=[0, 2], binary=binary))
    assert found == []
    assert back.n_freq == 300 and back.valid is None
    np.testing.assert_allclose(back.freq_hz, freq, rtol=5e-6)
    # Each line's values are the ones written for it (ASCII: 12 digits).
    np.testing.assert_allclose(back.H, frf.H, rtol=1e-10)


def test_truly_different_grids_are_warned_of(tmp_path):
    """One FRF every 0.5 Hz, the others every 0.25 Hz: the union of lines is kept, the coarse
    FRF blanked between its lines, and a warning says that the grids differ."""
    fine, coarse = chain_on(np.arange(1, 201) * 0.25), chain_on(np.arange(1, 101) * 0.5)
    datasets = frf_datasets("x", fine)
    functions = [d for d in datasets if d["type"] == 58]
    functions[2].update(x=coarse.freq_hz, data=coarse.H[:, 2, 0])
    for d in functions:
        d["abscissa_spacing"] = 1
    write_datasets(tmp_path / "grids.uff", datasets)
    back, found = read(tmp_path / "grids.uff")
    assert back.n_freq == 200 and (~back.valid).sum() == 100
    assert len(found) == 1 and "on different frequency grids" in found[0]
    assert "dataset 4 (0.5 to 50 Hz in steps of 0.5 Hz) lacks 99 line(s)" in found[0]


def test_two_lines_of_one_function_are_never_merged(tmp_path):
    """A binary (float64) FRF with lines 1e-9 relative apart (10 and 10.00000001 Hz) beside an
    ASCII FRF at 10 Hz, whose 6 digits cover both: the ASCII line joins one of them, the two
    binary lines stay two."""
    freq = np.array([5.0, 10.0, 10.00000001, 20.0])
    frf = chain_on(freq)
    datasets = frf_datasets("x", frf, binary=True)
    functions = [d for d in datasets if d["type"] == 58]
    keep = [0, 1, 3]
    functions[1].update(binary=0, x=freq[keep], data=frf.H[keep, 1, 0])
    write_datasets(tmp_path / "close.uff", datasets)
    back, found = read(tmp_path / "close.uff")
    assert found == [] and back.n_freq == 4
    np.testing.assert_array_equal(back.freq_hz, freq)
    np.testing.assert_array_equal(back.valid[:, 1, 0], [True, True, False, True])


def test_interleaved_grids_one_unit_of_the_sixth_digit_apart_stay_two_grids(tmp_path):
    """Two FRFs on dense interleaved grids, 1000.00 + 0.02 k and 1000.01 + 0.02 k Hz, both
    uneven ASCII (E13.5: 0.01 Hz is one unit of the 6th digit there). Merged as one grid they
    were 50 lines, each value of the second FRF put on the first's line 0.01 Hz away, with no
    warning (QA). They are 100 distinct lines, each FRF blanked on the other's."""
    fa = 1000.0 + 0.02 * np.arange(50)
    fb = fa + 0.01
    a, b = chain_on(fa), chain_on(fb)
    da = [d for d in frf_datasets("x", a) if d["type"] in (58, 164)]
    db = [d for d in frf_datasets("x", b) if d["type"] == 58]
    path = tmp_path / "interleaved.uff"
    write_datasets(path, [da[0], da[1], db[1]])  # the 164, H(1+Z) on grid a, H(2+Z) on grid b
    back, _ = read(path)
    assert back.n_freq == 100
    np.testing.assert_allclose(back.freq_hz, np.sort(np.r_[fa, fb]), atol=5e-3)
    i, j = back.outputs.index(a.outputs[0]), back.outputs.index(b.outputs[1])
    np.testing.assert_allclose(back.H[::2, i, 0], a.H[:, 0, 0], rtol=1e-10)
    np.testing.assert_allclose(back.H[1::2, j, 0], b.H[:, 1, 0], rtol=1e-10)
