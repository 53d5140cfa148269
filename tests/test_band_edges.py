"""Band processing at the record's edges (report section 5.2): a record shorter than one
band, bands too short for step 1, and the nested bands at the record's top end."""

from __future__ import annotations

import numpy as np
import pytest

from ssid.band_criteria import cluster_repeated, reject_top_nested_only
from ssid.bands import (
    BandRoot,
    band_min_lines,
    default_bands,
    high_edge_band,
    min_lines_for_two_bands,
    overlapping_bands,
    plot_band_roots,
    process_bands,
)
from ssid.frf import accelerance_from_model
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system
from ssid.models.payload import modal_damping
from ssid.noise import report_noise_frf


@pytest.fixture(scope="module")
def case():
    """As tests/test_bands.py's: 8 DOFs, modes 14.5 ... 477 Hz, 600 lines over 5-520 Hz."""
    M, C, K, dofs = example_system(8, seed=2)
    lam, _ = complex_modes(M, C, K)
    f_true = root_frequency_damping(lam)[0] / (2 * np.pi)
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(5, 520, 600), dofs, [dofs[1], dofs[5]])
    return M, C, K, f_true, frf



# --- Records shorter than one default band (a zoom sweep, a narrow --fmin/--fmax) ----------


def _payload_sweep(f_lo, f_hi, n_lines):
    """The payload's 16 Z DOFs (Guyan), 2 % modal damping, shakers at 11+Z and 16+Z, noise-free
    on ``n_lines`` log-spaced lines over [f_lo, f_hi] Hz; its 79.04 Hz mode lies in 60-100 Hz."""
    from ssid.models.payload import Z_DOFS, payload_simulator
    from ssid.tam import guyan_reduce

    p = payload_simulator()
    red = guyan_reduce(p.M, p.K, p.index(Z_DOFS))
    f = f_lo * np.geomspace(1.0, f_hi / f_lo, n_lines)
    return accelerance_from_model(red.M, modal_damping(red.M, red.K, 0.02), red.K, list(Z_DOFS),
                                  f, list(Z_DOFS), ["11+Z", "16+Z"])


def test_a_zoom_sweep_shorter_than_one_band_gets_overlapping_bands_and_confirms_its_mode():
    """22 lines over 60-100 Hz, fewer than the 24 of a default band: the layout is the record
    and its two part-bands, each holding the 10 lines step 1 needs at 16 sensors and two
    shakers, so the 79.04 Hz mode is found in two bands. Rounded to whole steps of 12 lines,
    the record was one band and the mode, a perfect root, was rejected as "not repeated"."""
    frf = _payload_sweep(60.0, 100.0, 22)
    need = band_min_lines(16, 2)
    bands = default_bands(frf.freq_hz, 0.5, need)
    f = frf.freq_hz
    held = [np.count_nonzero((f >= lo) & (f <= hi)) for lo, hi in bands]
    cover = sum(((f >= lo) & (f <= hi)).astype(int) for lo, hi in bands)
    assert len(bands) == 3 and min(held) >= need and cover.min() == 2
    res = process_bands(frf, bands, solver="ls")
    assert res.freq_hz.size == 1 and abs(res.freq_hz[0] / 79.0413 - 1) < 1e-4
    assert not res.warnings and not res.skipped


def test_too_few_lines_for_two_bands_is_said_not_reported_as_no_mode():
    """14 lines: no two overlapping bands hold 10 lines each (19 lines needed), so the record is
    one band, criterion 4 can confirm nothing, and the result says so rather than reading as
    a band without modes. Narrow --width bands skipped for too few lines are listed."""
    assert min_lines_for_two_bands(band_min_lines(16, 2)) == 19
    frf = _payload_sweep(60.0, 100.0, 14)
    bands = default_bands(frf.freq_hz, 0.5, band_min_lines(16, 2))
    assert bands == [(60.0, 100.0)]
    res = process_bands(frf, bands, solver="ls")
    assert res.freq_hz.size == 0
    assert len(res.warnings) == 1 and res.warnings[0].startswith("no root can be confirmed")
    res = process_bands(frf, overlapping_bands(60.0, 100.0, 30.0), solver="ls", low_edge=False,
                        high_edge=False)
    assert res.skipped and len(res.skipped) == len(res.bands_hz) - 1
    assert "1 of the" in res.warnings[0] and "criterion 4" in res.warnings[0]


def test_the_chart_of_one_band_numbers_it_zero(tmp_path, monkeypatch):
    """The band axis holds whole band numbers: a lone band is band 0, not ticks -0.04..0.04."""
    import matplotlib.pyplot as plt

    frf = _payload_sweep(60.0, 100.0, 14)
    res = process_bands(frf, [(60.0, 100.0)], solver="ls")
    figs = []
    monkeypatch.setattr(plt, "close", figs.append)
    plot_band_roots(str(tmp_path / "one.png"), res)
    ax = figs[0].axes[0]
    lo, hi = ax.get_ylim()
    assert [t for t in ax.get_yticks() if lo <= t <= hi] == [0.0]


# --- The record's high edge: the top part-band lies inside the band before it ---------------


def test_a_root_only_the_nested_top_bands_found_needs_the_high_edge_band():
    """Layout 0-400 Hz in bands of 200 Hz: the top part-band (300-400) lies wholly inside the
    band 200-400, so a root fitted to the noise of its lines comes out of both (a 1456.5 Hz
    root, 0.04 % damping, on the payload's one-shaker random record). Such a mode must be
    repeated by the high-edge band (index 5) too: a noise root it does not repeat is rejected,
    a mode it repeats (even as a resolved root, which otherwise confirms nothing) is kept, and
    a mode that a band not ending at the last line found needs nothing more."""
    lines = np.linspace(0.0, 400.0, 401)
    layout = [(0.0, 100.0), (0.0, 200.0), (100.0, 300.0), (200.0, 400.0), (300.0, 400.0)]
    high = len(layout) + 1  # after the low-edge band

    def root(band, f, zeta, rejected=""):
        r = BandRoot(band, complex(-zeta * f, f), np.ones(2), f, zeta, 0.99, rejected=rejected)
        r.high_edge = band == high
        return r

    noise = [root(3, 350.0, 0.001), root(4, 350.02, 0.001)]
    mode = [root(3, 330.0, 0.02), root(4, 330.1, 0.02),
            root(high, 330.3, 0.02, rejected="resolved (high-edge band)")]
    inner = [root(2, 250.0, 0.02), root(3, 250.1, 0.02)]
    roots = noise + mode + inner
    cluster_repeated(roots, 0.125, lines)
    assert all(r.cluster >= 0 for r in noise + mode[:2] + inner)
    reject_top_nested_only(roots, layout, high, 0.125, lines)
    assert [r.rejected for r in noise] == ["not repeated by the high-edge band"] * 2
    assert all(not r.rejected and r.cluster >= 0 for r in mode[:2] + inner)
    assert high_edge_band(layout, lines) == (100.0, 400.0)  # 1.5 times the 200 lines there


def test_the_high_edge_band_keeps_a_true_mode_of_the_top_part_band(case):
    """Report noise, bands of 150 Hz over 5-520 Hz: the 477 Hz mode lies in the top part-band
    (445-520 Hz) and the band it is nested in only; the high-edge band repeats it, so every
    mode is still found."""
    *_, f_true, frf = case
    res = process_bands(report_noise_frf(frf, seed=4), overlapping_bands(5, 520, 150, 0.5))
    high = res.high_edge_band
    assert high == len(res.bands_hz) - 1 and res.bands_hz[high][1] == 520.0
    top = [r for r in res.roots if r.cluster >= 0 and not r.rejected and abs(r.freq_hz - 477) < 5]
    assert {r.band for r in top if not r.high_edge} <= {high - 3, high - 2}  # the nested pair
    assert res.freq_hz.size == f_true.size
    assert np.max(np.abs(res.freq_hz - f_true) / f_true) < 1e-3
