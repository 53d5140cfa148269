"""Step-1 solvers on noisy broad-band data: the measurement behind the default solver.

The case: ``ssid.models.example_system`` (14 DOF, modes 9.8-437 Hz, damping 0.4-4 %,
non-proportional), all DOFs measured, three shakers, 1024 lines over 2-500 Hz, the report's
noise model (``addnoise``: 2 % magnitude, 2 degree phase, 40 averages, on responses and forces).
For each solver and seed it prints the largest natural-frequency error and damping error.

    python bench/noise_solvers.py [--seeds 10] [--solvers ml ls tls stls]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ssid.frf import accelerance_from_model
from ssid.identify import identify_mck
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system
from ssid.noise import report_noise_frf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--solvers", nargs="+", default=["ml", "ls", "tls", "stls"])
    ap.add_argument("--reactions", action="store_true",
                    help="8-DOF substructure on a test stand with measured reactions instead")
    args = ap.parse_args()

    if args.reactions:
        from ssid.models import frf_on_test_stand

        M, C, K, dofs = example_system(8, seed=2)
        clean = frf_on_test_stand(M, C, K, dofs, [dofs[2], dofs[5]], [dofs[0], dofs[7]],
                                  np.linspace(2, 500, 800))
    else:
        M, C, K, dofs = example_system(14, seed=1)
        clean = accelerance_from_model(M, C, K, dofs, np.linspace(2, 500, 1024), dofs,
                                       [dofs[0], dofs[6], dofs[12]])
    lam, _ = complex_modes(M, C, K)
    wn, zeta = root_frequency_damping(lam)
    f_true = wn / (2 * np.pi)
    print(f"{len(dofs)} DOF, {clean.n_in} inputs, {clean.n_freq} lines, "
          f"{'with' if args.reactions else 'without'} reactions; report noise model")
    print(f"{'solver':>6} {'seeds ok':>9} {'median max|df/f| %':>19} {'worst max|df/f| %':>18} "
          f"{'median max|dzeta/zeta| %':>25} {'mean s':>7}")
    for solver in args.solvers:
        errs, zerrs, times, ok = [], [], [], 0
        for seed in range(args.seeds):
            noisy = report_noise_frf(clean, seed=seed)
            t0 = time.perf_counter()
            r = identify_mck(noisy, solver=solver)
            times.append(time.perf_counter() - t0)
            if r.natural_freq_hz.size != f_true.size:
                errs.append(np.inf)
                zerrs.append(np.inf)
                continue
            e = np.max(np.abs(r.natural_freq_hz - f_true) / f_true)
            errs.append(e)
            zerrs.append(np.max(np.abs(r.damping_ratio - zeta) / zeta))
            ok += e < 0.01
        print(f"{solver:>6} {ok:>4}/{args.seeds:<4} {100 * np.median(errs):>19.4f} "
              f"{100 * np.max(errs):>18.4f} {100 * np.median(zerrs):>25.2f} {np.mean(times):>7.2f}")
    print("'seeds ok': every natural frequency within 1 % (inf: a mode was lost).")


if __name__ == "__main__":
    main()
