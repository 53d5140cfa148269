"""Band processing (report section 5.2) on a system with known M, C, K."""

from __future__ import annotations

import numpy as np
import pytest

from ssid.bands import overlapping_bands, plot_band_roots, process_bands, scale_selected_roots
from ssid.frf import accelerance_from_model
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system
from ssid.noise import report_noise_frf


@pytest.fixture(scope="module")
def case():
    M, C, K, dofs = example_system(8, seed=2)  # modes 14.5 ... 477 Hz
    lam, _ = complex_modes(M, C, K)
    f_true = root_frequency_damping(lam)[0] / (2 * np.pi)
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(5, 520, 600), dofs, [dofs[1], dofs[5]])
    return M, C, K, f_true, frf


def test_overlapping_bands_cover_every_line_twice():
    bands = overlapping_bands(5.0, 520.0, 150.0, 0.5)
    f = np.linspace(5, 520, 1000)
    cover = sum(((f >= lo) & (f <= hi)).astype(int) for lo, hi in bands)
    assert cover.min() >= 2


def test_noise_free_bands_find_every_mode_and_bp3_is_exact(case, tmp_path):
    M, C, K, f_true, frf = case
    res = process_bands(frf, overlapping_bands(5, 520, 150, 0.5), solver="ls")
    assert np.allclose(res.freq_hz, f_true, rtol=1e-6)
    u, mck = scale_selected_roots(frf, res, "BP3")
    assert mck is not None
    assert np.linalg.norm(mck[0] - M) / np.linalg.norm(M) < 1e-6
    assert np.linalg.norm(mck[2] - K) / np.linalg.norm(K) < 1e-6
    plot_band_roots(str(tmp_path / "bands.png"), res, f_true)
    assert (tmp_path / "bands.png").stat().st_size > 0


def test_noisy_bands_keep_true_modes_and_reject_noise_modes(case):
    """Report noise model, seed 4: the four criteria reject every computational root (each
    criterion fires at least once) and keep exactly the eight true modes."""
    M, C, K, f_true, frf = case
    noisy = report_noise_frf(frf, seed=4)
    res = process_bands(noisy, overlapping_bands(5, 520, 150, 0.5))
    assert res.freq_hz.size == f_true.size
    assert np.max(np.abs(res.freq_hz - f_true) / f_true) < 1e-3
    fired = {r.rejected for r in res.roots}
    assert {"outside band", "negative damping", "low MPC", "not repeated"} <= fired
    for method in ("BP1", "BP2", "BP3"):
        _, mck = scale_selected_roots(noisy, res, method)
        assert np.linalg.norm(mck[2] - K) / np.linalg.norm(K) < 0.03, method
