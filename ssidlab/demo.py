"""``ssidlab demo``: the main job, end to end, on the embedded default.

Until the simulated lab (drivers, simulated instruments, acquisition) exists, the demo is an
identification of a bundled example: a 14-DOF, non-proportionally damped spring-mass system
excited by three shakers, its accelerances synthesised from known M, C, K over 2-500 Hz and
corrupted with the report's noise model (2 % magnitude and 2 degree phase noise on responses
and forces, 40 averages). It is identified with the default settings of ``ssidlab identify``
and the result is compared with the truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ssid.frf import accelerance, accelerance_from_model, selection_matrix
from ssid.identify import identify_mck
from ssid.io import write_frf, write_model
from ssid.modal import complex_modes, root_frequency_damping
from ssid.models import example_system
from ssid.noise import report_noise_frf
from ssid.plots_correlation import plot_frf_overlay
from ssidlab.argtypes import write_json

__all__ = ["example_frf", "run_demo"]

EXAMPLE_SEED = 2026
EXAMPLE_FREQ_HZ = (2.0, 500.0, 1024)


def example_frf():
    """The bundled example: (noisy FRFData, true M, C, K, dofs)."""
    M, C, K, dofs = example_system(14, seed=1)
    freq = np.linspace(*EXAMPLE_FREQ_HZ)
    clean = accelerance_from_model(M, C, K, dofs, freq, dofs, [dofs[0], dofs[6], dofs[12]])
    noisy = report_noise_frf(clean, seed=EXAMPLE_SEED)
    noisy.attrs = {"source": "ssidlab demo example (report noise model)"}
    return noisy, M, C, K, dofs


def run_demo(out_dir: str, echo=print) -> dict:
    """Run the demo, write its files to ``out_dir`` and return the JSON summary."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    echo("[1/4] synthesising the bundled example instead of running the simulated lab "
         "(14 DOF, 3 shakers, 1024 lines, report noise model)")
    frf, M, C, K, dofs = example_frf()
    write_frf(str(out / "frf.h5"), frf)
    echo(f"      wrote {out / 'frf.h5'}")

    echo("[2/4] identifying M, C, K (default solver) ...")
    result = identify_mck(frf)
    write_model(str(out / "model.h5"), result.to_model())

    echo("[3/4] comparing with the true system")
    lam, _ = complex_modes(M, C, K)
    wn, zeta = root_frequency_damping(lam)
    f_true = wn / (2 * np.pi)
    rows = []
    n = min(f_true.size, result.natural_freq_hz.size)
    echo(f"      {'mode':>4} {'true Hz':>10} {'ident Hz':>10} {'err %':>8} "
         f"{'true zeta %':>11} {'ident zeta %':>12}")
    for k in range(n):
        err = 100 * (result.natural_freq_hz[k] - f_true[k]) / f_true[k]
        rows.append(err)
        echo(f"      {k + 1:>4} {f_true[k]:>10.3f} {result.natural_freq_hz[k]:>10.3f} "
             f"{err:>8.4f} {100 * zeta[k]:>11.3f} {100 * result.damping_ratio[k]:>12.3f}")
    max_err = float(np.max(np.abs(rows))) if rows else float("nan")
    m_err = float(np.linalg.norm(result.M - M) / np.linalg.norm(M))
    k_err = float(np.linalg.norm(result.K - K) / np.linalg.norm(K))
    echo(f"      max |frequency error| {max_err:.4f} %, M error {100 * m_err:.3f} %, "
         f"K error {100 * k_err:.3f} % (relative Frobenius)")
    for w in result.warnings:
        echo(f"      warning: {w}")

    echo("[4/4] writing result.json and frf_overlay.png")
    summary = result.to_json_dict()
    summary["demo"] = {
        "true_natural_freq_hz": f_true.tolist(),
        "max_abs_freq_error_percent": max_err,
        "M_rel_error": m_err,
        "K_rel_error": k_err,
    }
    write_json(out / "result.json", summary)
    i = 0
    H_id = accelerance(result.M, result.C, result.K, frf.omega,
                       selection_matrix(result.dofs, frf.inputs[:1]))[:, i, 0]
    plot_frf_overlay(
        frf.freq_hz, frf.H[:, i, 0], H_id, out / "frf_overlay.png",
        title=f"drive point {frf.outputs[i]} / {frf.inputs[0]}",
        labels=("measured (noisy)", "identified model"),
    )
    echo(f"done: {out}/frf.h5, model.h5, result.json, frf_overlay.png")
    return summary
