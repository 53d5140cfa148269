"""Pseudo-DOF models on the payload: the report's two partitions against the number chosen
from the data (``ssid.pseudo_dof_scan.identify_pseudo_dof_auto``), noise-free and noisy.

    python bench/pseudo_dof_partitions.py        # about a minute on 2 cores

Records: the payload simulator (section 6 of the report, our model) seen by the EfI sensors
of docs/replication.md (10, 12 or 16 Z DOFs), inputs at the interface DOFs, 1024 lines from
1 Hz, 2 % modal damping; noisy rows add the report's noise model with seed 1. Columns: the
number of partitions P, whether the repeat test settled, the modes of the band held by a
structural root within 1 % (one root per mode, closest first), and the structural roots
farther than 1 % from every mode of the band (false roots). This is the evidence behind the
numbers in docs/algorithm.md ("Band processing and pseudo-DOF models").
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from report_truth import Truth  # noqa: E402
from ssid.noise import report_noise_frf  # noqa: E402
from ssid.pseudo_dof import identify_pseudo_dof, matched_one_to_one  # noqa: E402
from ssid.pseudo_dof_scan import identify_pseudo_dof_auto  # noqa: E402

RECORDS = [(10, 300.0), (10, 600.0), (10, 1000.0), (10, 2100.0), (12, 2100.0), (16, 2100.0),
           (16, 3000.0)]


def held_and_false(roots_hz: np.ndarray, modes_hz: np.ndarray, rtol: float = 0.01) -> tuple[int, int]:
    """Modes with their own root within ``rtol`` (matched one to one), roots near no mode."""
    if roots_hz.size == 0:
        return 0, 0
    held = int(matched_one_to_one(modes_hz, roots_hz, rtol).sum())
    d = np.abs(roots_hz[None, :] - modes_hz[:, None]) / modes_hz[:, None]
    return held, int(np.sum(np.min(d, axis=0) >= rtol))


def main() -> None:
    truth = Truth()
    print("| sensors | band | data | modes in band | P = 2: held, false | chosen P | settled | held, false | time |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n, f_max in RECORDS:
        sensors, _ = truth.sensors(n)
        clean = truth.frf(sensors, (1.0, f_max, 1024))
        modes = truth.f[truth.f <= f_max]
        for label, frf in (("noise-free", clean), ("noisy, seed 1", report_noise_frf(clean, 1))):
            two = identify_pseudo_dof(frf, n_partitions=2)
            h2, f2 = held_and_false(two.freq_hz[two.structural], modes)
            t0 = time.perf_counter()
            auto = identify_pseudo_dof_auto(frf)
            dt = time.perf_counter() - t0
            ha, fa = held_and_false(auto.freq_hz[auto.structural], modes)
            print(f"| {n} | 1-{f_max:.0f} Hz | {label} | {modes.size} | {h2}, {f2} | "
                  f"{auto.scan.chosen} | {'yes' if auto.scan.settled else 'no'} | {ha}, {fa} | "
                  f"{dt:.1f} s |")


if __name__ == "__main__":
    main()
