"""A free test whose band misses modes: what ``identify`` writes as noise grows (diagnostic).

The payload on its bungees (``examples/setup_sim_free.toml``: 16 Z sensors, shakers at 11+Z
and 16+Z) over 150 log-spaced lines, 20-1500 Hz: 9 of its 16 modes in the band, the 3
suspension modes below it and 4 above. Noise: complex Gaussian, standard deviation a fixed
fraction of |H| per value, its variance given to the fit as ``H_var`` (as acquisition writes
it); seeds 1-3. Per case: the largest relative error of step 1's roots in the band against
the noise-free fit's, the written model's ``||H - H_model|| / ||H||`` over the band, whether
its M and K are definite, how far its M, K, C are from the simulated truth (Frobenius norm,
relative), and which damping matrix ``identify`` wrote (``output_error``: M, C, K refined to
the data; docs/algorithm.md, step 2 and known limits).

    python bench/free_test_noise.py [--levels 0.0002 0.001 0.0026] [--seeds 1 2 3]

About 35 s on one core.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: steady digits, one case at a time

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from daq.setup import parse_setup  # noqa: E402
from daq.simlab import build_world  # noqa: E402
from ssid.frf import FRFData  # noqa: E402
from ssid.identify import identify_mck  # noqa: E402

SENSORS = [f"{n}+Z" for n in (1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 13, 14, 15, 16, 17, 18)]
BAND_HZ = (20.0, 1500.0)


def free_world():
    path = ROOT / "examples" / "setup_sim_free.toml"
    return build_world(parse_setup(path.read_text(encoding="utf-8"), str(path)))


def free_record() -> FRFData:
    """Noise-free accelerances of the simulated free payload at the bench's lines."""
    return free_world().frf(np.geomspace(*BAND_HZ, 150), outputs=SENSORS, inputs=["11+Z", "16+Z"])


def true_matrices() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The simulated payload's M, C, K over SENSORS (its model has exactly these DOFs)."""
    M, C, K, dofs = free_world().coupled_model()
    at = [dofs.index(s) for s in SENSORS]
    return M[np.ix_(at, at)], C[np.ix_(at, at)], K[np.ix_(at, at)]


def with_noise(frf: FRFData, level: float, seed: int) -> FRFData:
    """``frf`` plus complex Gaussian noise of standard deviation ``level |H|``, its variance given."""
    rng = np.random.default_rng(seed)
    sd = level * np.abs(frf.H)
    noise = sd * (rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape)) / np.sqrt(2)
    return dataclasses.replace(frf, H=frf.H + noise, H_var=sd**2)


def off(A: np.ndarray, T: np.ndarray) -> float:
    """``||A - T|| / ||T||`` (Frobenius)."""
    return float(np.linalg.norm(A - T) / np.linalg.norm(T))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=float, nargs="+", default=[0.0002, 0.001, 0.0026])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = ap.parse_args()
    clean = free_record()
    ref = identify_mck(clean)
    f_ref = ref.natural_freq_hz[(ref.natural_freq_hz > BAND_HZ[0]) & (ref.natural_freq_hz < BAND_HZ[1])]
    print(f"noise-free: {f_ref.size} roots in the band; written model's FRF error "
          f"{ref.checks['frf_relative_rms_error']:.2g}\n")
    M, C, K = true_matrices()
    print("| noise (% of abs H) | seed | in-band roots, max error (%) | written model's FRF error (%) "
          "| M definite | K semi-definite | M, K, C off (%) | damping matrix |")
    print("|---|---|---|---|---|---|---|---|")
    for level in args.levels:
        for seed in args.seeds:
            r = identify_mck(with_noise(clean, level, seed))
            f = r.natural_freq_hz
            err = max(float(np.min(np.abs(f / x - 1))) for x in f_ref)
            print(f"| {100 * level:g} | {seed} | {100 * err:.2g} | {100 * r.checks['frf_relative_rms_error']:.3g} "
                  f"| {'yes' if r.checks['M_min_eig_rel'] > 0 else 'no'} "
                  f"| {'yes' if r.checks['K_min_eig_rel'] > -1e-9 else 'no'} "
                  f"| {', '.join(f'{100 * off(A, T):.3g}' for A, T in zip((r.M, r.K, r.C), (M, K, C)))} "
                  f"| {r.damping} |", flush=True)


if __name__ == "__main__":
    main()
