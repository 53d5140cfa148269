"""Do the noise-free data prefer a reduced-order model that holds every target? (diagnostic)

For section 2's reduced-order rows of the replication bench (payload model, noise-free
FRFs, EfI sensors) this compares two step-1 models on the same record and the same weights
(the ones our default ``ml`` fit ends with):

* ``default``: :func:`ssid.identify.identify_step1`, what a user gets;
* ``from SEREP``: the SEREP TAM of the target modes at the sensors (:func:`ssid.tam.serep_reduce`,
  2 % modal damping), which holds every target exactly, then refined by output error
  (Levenberg-Marquardt, 100 steps). It starts from the FE model, which a test does not
  have, so it is not a method: it shows whether the data's criterion keeps the targets.

If the refinement from SEREP lets targets go and ends *higher* in output error than the
default, the band's data prefer a model that does not hold them: a better search would not
fix that row. If it ends lower, the row is (also) the search's.
The first columns count modes: those below ``f_max`` (the non-targets among them with their
mass-normalised shape norm at the sensors: how strongly the data show them) and the targets
above it. A model of n DOFs holds n modes; one that held every mode its band shows would have
``n - (modes in band)`` pairs left for the targets above.
Frequency / damping: largest |% error| over the target modes paired by MAC and frequency
(as in the replication tables), misses in brackets; from step 1's roots and shapes, which
can differ from the replication table's cells (those are the written M, C, K's, and a start
with fewer problems may replace a refinement there).

    python bench/target_basins.py

About 2 minutes on two cores.
"""

from __future__ import annotations

import sys

import numpy as np
from report_truth import INTERFACE_DOFS, fmt, run_parallel, step1_root_errors, worker_truth

from ssid.identify import identify_step1
from ssid.models.payload import modal_damping
from ssid.step1 import Step1Estimate
from ssid.step1_refine import output_error_cost, refine_output_error
from ssid.tam import serep_reduce

#: (sensors, f_max in Hz): section 2's rows at the report's spectra and the equivalent ones,
#: 512 lines from 1 Hz; the 10-DOF 1-300 Hz row, which holds every target, as a control.
CASES = [(10, 300.0), (12, 300.0), (12, 650.0), (12, 551.0), (12, 1158.0),
         (16, 300.0), (16, 650.0), (16, 551.0), (16, 1158.0)]


def serep_start(truth, sensors, tm, Dr_hat: np.ndarray) -> Step1Estimate:
    """Step 1's matrices (M^-1 C, M^-1 K, M^-1 at the inputs; Eq. 3.8) of the SEREP TAM
    of the target modes ``tm`` at ``sensors``, with 2 % modal damping."""
    tam = serep_reduce(truth.p.M, truth.p.K, truth.p.index(sensors), targets=tm)
    C = modal_damping(tam.M, tam.K, 0.02)
    inputs = [sensors.index(s) for s in INTERFACE_DOFS]
    return Step1Estimate(np.linalg.solve(tam.M, C), np.linalg.solve(tam.M, tam.K),
                         np.linalg.inv(tam.M)[:, inputs], Dr_hat.copy())


def one_row(n: int, f_max: float) -> str:
    truth = worker_truth()
    sensors, tm = truth.sensors(n)
    frf = truth.frf(sensors, (1.0, f_max, 512))
    est, d, _ = identify_step1(frf)
    cost = output_error_cost(d, est)
    start = serep_start(truth, sensors, tm, est.Dr_hat)
    alt, info = refine_output_error(d, start, max_iter=100)
    in_band = np.flatnonzero(truth.f < f_max)
    seen = np.linalg.norm(truth.phi[truth.p.index(sensors)], axis=0)
    others = ", ".join(f"{truth.f[i]:.1f} ({seen[i]:.2f})" for i in in_band if i not in set(tm))
    counts = f"{in_band.size} ({others or 'all targets'}) | {int(np.sum(truth.f[tm] >= f_max))}"
    return (f"| {n}-DOF | 1-{f_max:g} Hz | {counts} | {cost:.4g} | {fmt(*step1_root_errors(truth, sensors, tm, est))} "
            f"| {output_error_cost(d, start):.4g} | {info['cost']:.4g} "
            f"| {fmt(*step1_root_errors(truth, sensors, tm, alt))} | {info['cost'] / cost:.3g} |")


def main() -> int:
    print("| model | spectrum | modes in band (non-targets, Hz (shape norm)) | targets above "
          "| default: cost | default: errors | SEREP: cost | from SEREP: cost "
          "| from SEREP: errors | cost ratio (from SEREP / default) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for line in run_parallel(one_row, CASES, size=[n * f for n, f in CASES]):
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
