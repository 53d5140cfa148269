"""``ssidlab demo``: the main job on the simulated lab, end to end.

1. Start the simulated lab - the payload simulator (16 Z DOFs) on a three-post test stand,
   shakers at two interior DOFs (11+Z, 16+Z) fed by one two-channel generator and two
   amplifiers, 16 accelerometers, load cells at the interface DOFs (4+Z, 8+Z, 18+Z), all on
   a CAN FD DAQ, and a hidden effect the nominal model lacks (0.25 kg at 6+Z) - and run a
   stepped-sine test with coherence blanking through the real drivers (``daq``).
2. Identify the substructure's M, C, K with SSID from the accelerances and the measured
   reaction forces (``ssid.identify.identify_mck``).
3. Correlate the identified model with the FE model (the nominal payload model: MAC,
   frequency errors, orthogonality) and with the truth of the simulated world.
4. Run the discrepancy workflow on the measured FRFs against the nominal model as mounted
   (the FE payload model plus the stand, which the demo takes as known), never told the
   hidden effect: it names the effect, adds it and reports the gap before and after. Then
   again with the FE payload model alone, loaded by the measured reactions as the test
   article was (what a lab without a model of its stand would do). (The SSID-isolated
   substructure is not used here: its out-of-band modes are too uncertain to localise a
   0.25 kg mass against.)
5. Write FRF (HDF5 and UFF 58), models, JSON summaries and PNG plots to the output folder.

The test setup is :func:`demo_setup_text` (also ``examples/setup_sim.toml``).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

# The demo runs the simulated lab's example setup; its names, as the demo calls them.
from daq.simlab import EXAMPLE_HIDDEN as HIDDEN
from daq.simlab import EXAMPLE_SHAKERS as DEMO_SHAKERS
from daq.simlab import example_setup_text as demo_setup_text

__all__ = ["DEMO_SHAKERS", "demo_setup_text", "run_lab_demo"]


def _progress(echo, every_s: float = 2.0):
    """Progress lines of the run, at most one every ``every_s`` seconds (plus notes)."""
    last = [0.0]

    def show(msg: str) -> None:
        now = time.monotonic()
        if not msg.startswith("  shaker") or now - last[0] >= every_s:
            last[0] = now
            echo("      " + msg.strip())

    return show


def run_lab_demo(out_dir: str, echo=print) -> dict:
    """Run the demo, write its files to ``out_dir`` and return the JSON summary."""
    from daq.run import run_test
    from daq.setup import parse_setup
    from daq.simlab import build_world, nominal_model, payload_substructure
    from ssid.correlate_models import correlate_models
    from ssid.discrepancy import find_discrepancy
    from ssid.discrepancy.plots import write_plots
    from ssid.frf import accelerance_under_test_loads
    from ssid.identify import identify_mck
    from ssid.io import Model, read_frf, write_model
    from ssid.modal import complex_modes, root_frequency_damping
    from ssid.plots_correlation import plot_frequency_errors, plot_frf_overlay, plot_mac_matrix
    from ssidlab.argtypes import write_json
    from ssidlab.cli_correlate import jsonable

    t0 = time.monotonic()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    frf_path, uff_path = out / "frf.h5", out / "frf.uff"
    for p in (frf_path, uff_path):
        p.unlink(missing_ok=True)
    setup = parse_setup(demo_setup_text(), "demo setup")
    setup = dataclasses.replace(setup, output_file=str(frf_path), uff_file=str(uff_path))
    (out / "setup.toml").write_text(setup.text, encoding="utf-8")

    echo("[1/5] simulated lab: payload simulator on a 3-post stand, shakers at 11+Z and 16+Z, "
         "16 accelerometers, load cells at 4+Z 8+Z 18+Z, hidden effect; stepped sine 20-1500 Hz")
    acq = run_test(setup, sim=True, echo=_progress(echo))
    t_acq = time.monotonic() - t0
    echo(f"      {acq['n_lines']} lines x {len(setup.shakers)} shakers, {acq['n_values_blanked']} values "
         f"blanked, {acq['test_time_s']:.0f} s of test time in {t_acq:.0f} s; wrote {frf_path}, {uff_path}")
    frf = read_frf(frf_path)

    echo("[2/5] identifying the substructure (SSID, accelerances + measured reactions) ...")
    res = identify_mck(frf)
    ident = res.to_model()
    write_model(out / "model.h5", ident)
    write_json(out / "result.json", res.to_json_dict())

    echo("[3/5] correlating with the FE model (nominal payload model) and with the simulated truth")
    M, C, K, dofs = payload_substructure(0.02)
    fe = Model(M=M, K=K, C=C, dofs=dofs)
    write_model(out / "fe_model.h5", fe)
    study = correlate_models(ident, fe)
    world = build_world(setup)
    lam, _ = complex_modes(world.M_s, world.C_s, world.K_s)
    f_true = root_frequency_damping(lam)[0] / (2 * np.pi)
    f_fe = root_frequency_damping(complex_modes(M, C, K)[0])[0] / (2 * np.pi)
    f_id = res.natural_freq_hz
    n = min(f_true.size, f_id.size)
    err_true = 100 * (f_id[:n] - f_true[:n]) / f_true[:n]
    corr = jsonable(study.summary)
    pairs = corr["paired_modes"]
    # The FE columns follow the MAC pairing, not the mode numbers: the hidden mass mixes the
    # close pair near 313-322 Hz, so the identified 7th mode is the FE model's 8th.
    fe_of = {p["test_mode"]: p for p in pairs}
    echo(f"      {'mode':>4} {'ident Hz':>9} {'zeta %':>6} {'true Hz':>9} {'id-true %':>9} "
         f"{'FE mode':>7} {'FE Hz':>9} {'id-FE %':>8} {'MAC':>5}")
    for k in range(n):
        p = fe_of.get(k + 1)
        fe_cells = (f"{p['analysis_mode']:>7} {p['analysis_freq_hz']:>9.2f} "
                    f"{p['freq_error_percent']:>8.3f} {p['mac']:>5.2f}" if p else
                    f"{'-':>7} {'-':>9} {'-':>8} {'-':>5}")
        echo(f"      {k + 1:>4} {f_id[k]:>9.2f} {100 * res.damping_ratio[k]:>6.2f} {f_true[k]:>9.2f} "
             f"{err_true[k]:>9.3f} {fe_cells}")
    in_band = (f_true[:n] >= frf.freq_hz[0]) & (f_true[:n] <= frf.freq_hz[-1])
    write_json(out / "correlation.json", corr)
    shifted = [p for p in pairs if abs(p["freq_error_percent"]) > 1.0]
    echo(f"      identified vs truth: max |error| {np.max(np.abs(err_true[in_band])):.3f} % over the "
         f"{int(in_band.sum())} modes in the band {frf.freq_hz[0]:g}-{frf.freq_hz[-1]:g} Hz, "
         f"{np.max(np.abs(err_true)):.2f} % over all {n} (suspension modes below and modes above the band)")
    echo(f"      identified vs FE model: {len(pairs)} modes paired by MAC; {len(shifted)} shifted by more "
         f"than 1 % (the hidden effect): " + ", ".join(
             f"FE mode {p['analysis_mode']} {p['freq_error_percent']:+.2f} %" for p in shifted))
    for w in res.warnings:
        echo(f"      warning: {w}")

    echo("[4/5] discrepancy workflow: the measured FRFs against the nominal model as mounted "
         "(FE payload + stand), never told the hidden effect")
    nominal = nominal_model(setup)
    write_model(out / "nominal_mounted.h5", nominal)
    measured = dataclasses.replace(frf, H_reaction=None, H_reaction_var=None, reactions=None)
    disc = find_discrepancy(nominal, measured)
    dj = disc.to_json_dict()
    write_json(out / "discrepancy.json", dj)
    write_model(out / "updated_model.h5", disc.updated_model)
    (out / "discrepancy").mkdir(exist_ok=True)
    write_plots(disc, out / "discrepancy")
    params = ", ".join(f"{k} {v:.4g}" for k, v in dj["parameters"].items())
    echo(f"      named: {dj['effect']} at {', '.join(dj['dofs'])} ({params}); "
         f"{dj['gap_metric']} {dj['gap_before']:.3g} -> {dj['gap_after']:.3g}")
    # No stand model: the payload model alone, loaded by the measured reactions (the data
    # decide whether to apply them; the line says which way it went).
    sub = find_discrepancy(fe, frf).to_json_dict()
    write_json(out / "discrepancy_substructure.json", sub)
    params = ", ".join(f"{k} {v:.4g}" for k, v in sub["parameters"].items())
    how = "loaded by the measured reactions" if sub["reactions"]["applied"] else "the reactions not applied"
    echo(f"      the FE payload alone, {how}: {sub['effect']} at {', '.join(sub['dofs'])} ({params}); "
         f"{sub['gap_metric']} {sub['gap_before']:.3g} -> {sub['gap_after']:.3g}")
    echo(f"      hidden in the simulated lab: {HIDDEN}")

    echo("[5/5] writing plots and summary.json")
    # The identified model is the free substructure; on the stand it also feels the measured
    # reactions.
    i_drv = frf.outputs.index(frf.inputs[0])
    H_id = accelerance_under_test_loads(res.M, res.C, res.K, list(res.dofs), frf)[:, i_drv, 0]
    plot_frf_overlay(frf.freq_hz, frf.H[:, i_drv, 0], H_id, out / "frf_overlay.png",
                     title=f"drive point {frf.inputs[0]} on the stand: measured vs identified",
                     labels=("measured (simulated lab)", "identified model + measured reactions"),
                     valid=frf.valid[:, i_drv, 0])
    plot_mac_matrix(study.mac, out / "mac.png", study.test_freq_hz, study.analysis_freq_hz,
                    title="MAC: identified (rows) vs FE model (columns)")
    plot_frequency_errors(pairs, out / "freq_errors.png", title="identified vs FE model: frequency error")
    _plot_sweep(frf_path, out / "sweep.png")
    summary = {
        "acquisition": acq,
        "identification": {
            "natural_freq_hz": [float(v) for v in f_id], "damping_ratio": [float(v) for v in res.damping_ratio],
            "true_natural_freq_hz": [float(v) for v in f_true], "fe_natural_freq_hz": [float(v) for v in f_fe],
            "freq_error_vs_truth_percent": [float(v) for v in err_true],
            "max_abs_freq_error_in_band_percent": float(np.max(np.abs(err_true[in_band]))),
            "M_rel_error": float(np.linalg.norm(res.M - world.M_s) / np.linalg.norm(world.M_s)),
            "K_rel_error": float(np.linalg.norm(res.K - world.K_s) / np.linalg.norm(world.K_s)),
            "warnings": list(res.warnings),
        },
        "correlation": {"paired_modes": pairs, "shifted_modes": shifted},
        "hidden_effect": HIDDEN,
        "discrepancy": {k: dj[k] for k in ("effect", "dofs", "parameters", "gap_before", "gap_after",
                                           "gap_metric")},
        "discrepancy_substructure": {k: sub[k] for k in ("effect", "dofs", "parameters", "gap_before",
                                                         "gap_after", "gap_metric", "reactions")},
        "runtime_s": time.monotonic() - t0,
        "files": _files_written(out),
    }
    write_json(out / "summary.json", summary)
    echo(f"done in {summary['runtime_s']:.0f} s: {out}/ " + ", ".join(summary["files"]))
    return summary


def _files_written(out: Path) -> list[str]:
    """The names in ``out`` once the demo is done, ``summary.json`` among them though the
    list is made before it is written (it goes into that file)."""
    return sorted({p.name for p in out.iterdir()} | {"summary.json"})


def _plot_sweep(frf_path: Path, png: Path) -> None:
    """Lines chosen by the sweep and the settle time spent on each."""
    import h5py
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with h5py.File(frf_path, "r") as f:
        r = {k: f["acq/records"][k][()] for k in ("freq_hz", "settle_s", "dwell_s", "pattern")}
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for p in np.unique(r["pattern"]):
        m = r["pattern"] == p
        ax.semilogx(r["freq_hz"][m], r["settle_s"][m], ".", label=f"settle, shaker {p + 1}")
    ax.semilogx(r["freq_hz"], r["dwell_s"], "k_", ms=4, label="dwell")
    ax.set_xlabel("frequency, Hz")
    ax.set_ylabel("time per line, s")
    ax.set_title("stepped sine: settling follows the transient decay")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
