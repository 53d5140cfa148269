"""Is a noisy reduced-order row limited by the data or by the search? (diagnostic)

For section 3's noisy records of the replication bench (payload model, the report's noise,
seeds 1-3) this compares two step-1 models on the *same* noisy record and the same noise
weights (the ones our default ``ml`` fit ends with):

* ``default``: :func:`ssid.identify.identify_step1`, what a user gets;
* ``from noise-free``: the ``ml`` fit of the noise-free record, refined on the noisy one
  (Levenberg-Marquardt, 60 steps). It starts from data a test never has, so it is not a
  method: it shows where a minimum of the noisy record's output error lies.

When the second is many times lower in weighted output error, the data prefer a model the
default search does not reach, and the row's misses are the search's, not the noise's.
Frequency / damping: largest |% error| over the target modes paired by MAC and frequency
(as in the replication tables), misses in brackets; from step 1's roots and shapes.

    python bench/noisy_basins.py [--seeds 1 2 3]

About 1 minute on one core.
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: steady, one case at a time

from report_truth import fmt, step1_root_errors, worker_truth  # noqa: E402

from ssid.identify import identify_step1  # noqa: E402
from ssid.noise import report_noise_frf  # noqa: E402
from ssid.step1_refine import output_error_cost, refine_output_error  # noqa: E402

#: (sensors, spectrum, label): the report's spectrum rows that miss targets under noise, and
#: the equivalent 10-DOF spectrum whose row holds them all, as a control.
CASES = [(10, (1.0, 300.0, 512), "1-300 Hz"),
         (12, (1.0, 650.0, 512), "1-650 Hz"),
         (10, (1.0, 551.0, 512), "1-551 Hz (as 300 Hz)")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = ap.parse_args(argv)
    truth = worker_truth()
    print("| model | spectrum | seed | default: cost | default: errors | from noise-free: cost "
          "| from noise-free: errors | cost ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for n, spectrum, label in CASES:
        sensors, tm = truth.sensors(n)
        clean = truth.frf(sensors, spectrum)
        est_clean, _, _ = identify_step1(clean)
        for seed in args.seeds:
            est, d, _ = identify_step1(report_noise_frf(clean, seed=seed))
            cost = output_error_cost(d, est)
            alt, info = refine_output_error(d, est_clean, max_iter=60)
            print(f"| {n}-DOF | {label} | {seed} | {cost:.4g} | {fmt(*step1_root_errors(truth, sensors, tm, est))} "
                  f"| {info['cost']:.4g} | {fmt(*step1_root_errors(truth, sensors, tm, alt))} "
                  f"| {cost / info['cost']:.3g} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
