"""Why band processing refuses records with interface reactions: step 1 over a narrow band.

Section 6's record of the report-replication bench (the payload's 16-DOF substructure on
three test stands: two applied forces, three reactions, 512 lines 1-1000 Hz), noise-free.
For each band, step 1 by least squares and its roots, against the substructure's own modes
in the band; and the conditioning of the step-1 regressor (columns scaled to unit norm): its
smallest singular values over its largest. For comparison, the same 16 Z sensors and bands
with three applied forces at the interface DOFs and no reactions (a free 52-DOF payload: a
reduced-order fit, section 4's setting).

Then band processing over the record, noise-free and with the report's noise (seeds 1-3), with
the default bands and with bands of 400 Hz.

Run from the repository root: ``python bench/reaction_bands.py`` (about a minute). Prints a
table; writes nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.linalg as sla

sys.path.insert(0, str(Path(__file__).resolve().parent))

from replicate_reactions import stand_record  # noqa: E402
from report_truth import Truth  # noqa: E402

from ssid.band_select import default_band_width_hz  # noqa: E402
from ssid.bands import overlapping_bands, process_bands  # noqa: E402
from ssid.frf import FRFData  # noqa: E402
from ssid.identify import identify_step1  # noqa: E402
from ssid.modal import root_frequency_damping  # noqa: E402
from ssid.noise import report_noise_frf  # noqa: E402
from ssid.step1 import step1_data, step1_regressors  # noqa: E402
from ssid.step2 import state_space_modes  # noqa: E402

BANDS_HZ = [(1.0, 1000.0), (500.0, 1000.0), (700.0, 1000.0), (750.0, 900.0), (790.0, 870.0)]


def regressor_conditioning(frf: FRFData) -> np.ndarray:
    """The three smallest singular values of the step-1 regressor over its largest, its
    columns (the unknowns of one DOF's row, Eq. 3.7) first scaled to unit norm."""
    d = step1_data(frf)
    Z = step1_regressors(d, d.H).reshape(-1, d.p)
    A = np.vstack([Z.real, Z.imag])
    A = A / np.linalg.norm(A, axis=0)
    s = np.linalg.svd(A, compute_uv=False)
    return s[-3:][::-1] / s[0]


def worst_mode_error(frf: FRFData, true_hz: np.ndarray) -> tuple[float, int]:
    """Step 1 (LS) on ``frf``: the largest relative error (%) of the true modes inside its
    band, each against the nearest root, and how many of them are more than 1 % off."""
    est, _, _ = identify_step1(frf, solver="ls")
    modes = state_space_modes(est.C_hat, est.K_hat)
    wn, _ = root_frequency_damping(modes.lam[: modes.n_pairs])
    f = wn / (2 * np.pi)
    inside = true_hz[(true_hz >= frf.freq_hz[0]) & (true_hz <= frf.freq_hz[-1])]
    err = np.array([100 * np.min(np.abs(f - x)) / x for x in inside])
    return (float(err.max()) if err.size else float("nan")), int(np.sum(err > 1.0))


def main() -> None:
    truth = Truth()
    frf, Ms, _, Ks = stand_record(truth)
    true_hz = np.sqrt(sla.eigvalsh(Ks, Ms)) / (2 * np.pi)
    sensors, _ = truth.sensors(16)
    free = truth.frf(sensors, (1.0, 1000.0, 512))  # three applied forces, no reactions
    print("step 1 (LS) per band, noise-free; sv: smallest singular values / largest")
    print(f"{'band Hz':>12} {'lines':>5} | {'with reactions: worst mode %':>29} {'sv':>30}"
          f" | {'3 inputs, no reactions: sv':>30}")
    for lo, hi in BANDS_HZ:
        sub = frf.band(lo, hi)
        err, n_bad = worst_mode_error(sub, true_hz)
        sv = " ".join(f"{x:9.2e}" for x in regressor_conditioning(sub))
        sv_free = " ".join(f"{x:9.2e}" for x in regressor_conditioning(free.band(lo, hi)))
        print(f"{lo:5.0f}-{hi:<6.0f} {sub.n_freq:5d} | {err:20.3g} ({n_bad} > 1 %) {sv:>30}"
              f" | {sv_free:>30}")
    f = frf.freq_hz
    inband = true_hz[true_hz <= f[-1]]
    print("\nband processing (50 % overlap); modes in the record: "
          + ", ".join(f"{x:.2f}" for x in inband) + " Hz")
    for width in (default_band_width_hz(f), 400.0):
        bands = overlapping_bands(float(f[0]), float(f[-1]), width, 0.5)
        for seed in (0, 1, 2, 3):
            data = frf if seed == 0 else report_noise_frf(frf, seed=seed)
            res = process_bands(data, bands, solver="ls" if seed == 0 else "ml")
            found = sum(1 for x in inband
                        if res.freq_hz.size and np.min(np.abs(res.freq_hz - x)) < 0.01 * x)
            what = "noise-free, LS" if seed == 0 else f"report's noise seed {seed}, ml"
            print(f"  bands of {width:.0f} Hz, {what}: {found} of {inband.size} modes within 1 %;"
                  " selected " + (", ".join(f"{x:.2f}" for x in res.freq_hz) or "none") + " Hz")


if __name__ == "__main__":
    main()
