"""How long ``find_discrepancy`` takes on the payload: 52 DOF, 16 outputs, 3 inputs, 1000 lines.

The baseline, measured in the same process just before each case, is one synthesis of the
nominal model's accelerance over the same lines, outputs and inputs
(``ssid.frf.accelerance_from_model``: one batched solve of the 52 x 52 dynamic stiffness per
line), the least any search over the model must do once. The table gives each variant's best
time over ``--repeat`` runs, its ratio to that baseline (how many model FRF syntheses the
whole workflow costs) and the search's share of that run (``info["timing_s"]["search"]``).

Variants, on the seeded case ``make_case(7, "payload", "added_mass", n_lines=1000,
n_outputs=16, n_inputs=3)`` (and the same case with the nominal model given without C):

* ``search only``: one round, no second round (``second_round=False``);
* ``default``: the search, the second round, the calibration check and the report;
* ``without C``: the nominal model without C (damping ratio searched too).

Run:  python bench/discrepancy_speed.py [--repeat 3] [--threads N]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time


def _best(fn, repeat: int) -> tuple[float, object]:
    """Best time of ``repeat`` calls of ``fn`` and that call's result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        t = time.perf_counter() - t0
        if t < best:
            best, out = t, result
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per variant, best kept (default 3)")
    ap.add_argument("--threads", type=int, default=None,
                    help="BLAS threads (sets OPENBLAS/OMP/MKL_NUM_THREADS before NumPy loads)")
    args = ap.parse_args()
    if args.threads is not None:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(args.threads)
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    import numpy as np

    from ssid.discrepancy import find_discrepancy
    from ssid.discrepancy.cases import make_case
    from ssid.frf import accelerance_from_model

    print(f"discrepancy speed: Python {platform.python_version()}, NumPy {np.__version__}, "
          f"CPUs {os.cpu_count()}, load {os.getloadavg()[0]:.2f}, BLAS threads "
          f"{os.environ.get('OPENBLAS_NUM_THREADS', 'default')}")
    kw = dict(structure="payload", effect="added_mass", n_lines=1000, n_outputs=16, n_inputs=3)
    damped = make_case(7, undamped_nominal=False, **kw)
    undamped = make_case(7, undamped_nominal=True, **kw)
    print(f"case: {damped.nominal.n} DOF, {damped.frf.n_out} outputs, {damped.frf.n_in} inputs, "
          f"{damped.frf.n_freq} lines (the case without C draws its own hidden mass)\n")
    variants = [
        ("search only", damped, dict(second_round=False)),
        ("default", damped, {}),
        ("without C", undamped, {}),
    ]
    print(f"{'variant':<12} {'baseline_s':>10} {'time_s':>8} {'ratio':>7} {'search_s':>9}  named (hidden)")
    for label, case, options in variants:
        m, f = case.nominal, case.frf
        C = damped.nominal.C  # a model without C costs the same per synthesis
        base, _ = _best(lambda: accelerance_from_model(m.M, C, m.K, m.dofs, f.freq_hz, f.outputs, f.inputs),
                        args.repeat)
        t, res = _best(lambda: find_discrepancy(m, f, **options), args.repeat)
        named = res.effect.describe() if res.effect.name != "none" else "none"
        print(f"{label:<12} {base:>10.3f} {t:>8.2f} {t / base:>7.0f} {res.info['timing_s']['search']:>9.2f}  "
              f"{named} ({case.truth.describe()})")


if __name__ == "__main__":
    main()
