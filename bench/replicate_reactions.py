"""Section 6 of the report-replication bench (bench/replicate_report.py): reaction forces, the
payload's Guyan substructure identified full order through three 9-DOF test stands (report
section 6.6), noise-free and with the report's noise."""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from report_truth import REPORT, Truth, fmt
from target_status import TargetRow

from ssid.correlate import modal_assurance, pair_modes_by_mac
from ssid.frf import FRFData, selection_matrix
from ssid.identify import identify_mck
from ssid.models.payload import INTERFACE_DOFS, Z_DOFS, attach_test_stand, rayleigh_damping
from ssid.noise import report_noise_frf
from ssid.step1 import Step1Estimate
from ssid.step1_refine import errors_in_variables_cost
from ssid.tam import guyan_reduce


def stand_record(truth: Truth) -> tuple[FRFData, np.ndarray, np.ndarray, np.ndarray]:
    """Section 6's noise-free record and the true substructure.

    The payload's 16-DOF Guyan substructure (its Z DOFs) on three 9-DOF test stands,
    coupled 25-DOF Guyan model with Rayleigh damping (2 % at 10 and 1000 Hz); inputs at 11+Z
    and 16+Z, reactions at the interface DOFs 4+Z, 8+Z, 18+Z; 512 lines 1-1000 Hz.

    Returns
    -------
    frf : accelerances (512, 16, 2) with the reactions (512, 3, 2).
    Ms, Cs, Ks : (16, 16) the substructure's M, C, K (C: the same Rayleigh damping).
    """
    p = truth.p
    M, K, dofs, T_rel = attach_test_stand(p)
    stand_z = [d for d in dofs[p.n:] if d.endswith("+Z")]
    keep = Z_DOFS + stand_z
    idx = [dofs.index(d) for d in keep]
    red = guyan_reduce(M, K, idx)  # 25-DOF coupled model, as the report's
    Mc, Kc = red.M, red.K
    a, b = 2 * 0.02 * (2 * np.pi) ** 2 * 10 * 1000 / (2 * np.pi * 1010), 2 * 0.02 / (2 * np.pi * 1010)
    Cc = rayleigh_damping(Mc, Kc, 10.0, 1000.0, 0.02)
    sub = guyan_reduce(p.M, p.K, p.index(Z_DOFS))  # the "true" 16-DOF substructure
    Ms, Ks = sub.M, sub.K
    Cs = a * Ms + b * Ks
    f = np.linspace(1.0, 1000.0, 512)
    w = 2 * np.pi * f
    inputs = ["11+Z", "16+Z"]
    D = selection_matrix(keep, inputs)
    Z = Kc[None] - (w**2)[:, None, None] * Mc[None] + 1j * w[:, None, None] * Cc[None]
    X = np.linalg.solve(Z, np.broadcast_to(D.astype(complex), (w.size,) + D.shape))
    T = np.zeros((3, len(keep)))
    for c, lbl in enumerate(INTERFACE_DOFS):
        T[c, keep.index(lbl)] = -1.0
        T[c, keep.index(stand_z[3 * c + 2])] = 1.0
    kc = 2e6
    Hr = (kc * (1 + 1j * w * b))[:, None, None] * np.einsum("rq,kqj->krj", T, X)
    H = -(w**2)[:, None, None] * X[:, : len(Z_DOFS)]
    frf = FRFData(freq_hz=f, H=H, outputs=list(Z_DOFS), inputs=inputs, H_reaction=Hr,
                  reactions=list(INTERFACE_DOFS))
    return frf, Ms, Cs, Ks


def reactions(truth: Truth, seeds: list[int]):
    """Section 6 as ``replicate_report.Section``: one job per record, and its printer."""
    frf, Ms, Cs, Ks = stand_record(truth)
    f = frf.freq_hz
    lam, phi_s = sla.eigh(Ks, Ms)
    fs = np.sqrt(lam) / (2 * np.pi)
    # Fair measure: the substructure modes inside the measured band (11 of 16: the 16-DOF model
    # has 5 modes above 1000 Hz), paired by MAC; the three suspension modes (1.3-6.2 Hz) fall
    # between the first lines (spacing 1.95 Hz, half-power width 2 zeta f < 0.3 Hz) where the
    # accelerance is far below the report's noise floor (0.3 % of each FRF's RMS), so they
    # are listed apart. The split is for reporting only; the identification never sees it.
    inband = np.flatnonzero(fs <= f[-1])
    low = inband[fs[inband] < 10.0]
    mid = inband[fs[inband] >= 10.0]
    sub_model = (Ms, Cs, Ks, fs, phi_s, inband, low, mid)
    records = [("noise-free", frf)] + [(f"noisy seed {s}", report_noise_frf(frf, seed=s))
                                       for s in seeds]
    # About 2 s noise-free and 18-24 s per noisy record on one core.
    jobs = [(reaction_row, (label, data, sub_model), 2.0 if label == "noise-free" else 20.0)
            for label, data in records]

    def show(rows: list[tuple[str, TargetRow]]) -> None:
        print("\n## 6. Reaction forces: substructure on three 9-DOF test stands (section 6.6)\n")
        print("16-DOF Guyan substructure; coupled 25-DOF Guyan model with Rayleigh damping; inputs "
              "at 11+Z and 16+Z; reactions at 4+Z, 8+Z, 18+Z; 512 lines 1-1000 Hz; substructure "
              f"modes in the band: {inband.size} of 16 ({fs[inband[0]]:.3g}-{fs[inband[-1]]:.4g} Hz)")
        print(f"- report: {REPORT['reactions']}")
        for line, status in rows:
            print(line)
            truth.status.append(status)
        print(REACTION_NOTES)

    return jobs, show


def reaction_row(label: str, data: FRFData, sub_model: tuple) -> tuple[str, TargetRow]:
    """Section 6's lines for one record (worker process): the identified substructure
    against the true one and, for noisy data, the errors-in-variables cost of both; and the
    Target's row."""
    Ms, Cs, Ks, fs, phi_s, inband, low, mid = sub_model
    r = identify_mck(data)
    cost = ""
    if label != "noise-free":
        # The same cost at the true substructure: is the minimum the search missed there?
        # Step 1's own data and weights (r.step1), which the true model's cost needs.
        est, d = r.step1
        Mi = np.linalg.inv(Ms)
        true_est = Step1Estimate(Mi @ Cs, Mi @ Ks, Mi[:, d.in_idx], Mi[:, d.r_idx])
        cost = (f"\n  errors-in-variables cost (step 1, {d.omega.size * d.n * d.n_in} complex "
                f"equations): true substructure {errors_in_variables_cost(d, true_est):.3g}, "
                f"our estimate {errors_in_variables_cost(d, est):.3g}")
    em = max(np.max(np.abs(A - B)) / np.max(np.abs(B)) for A, B in ((r.M, Ms), (r.K, Ks)))
    ec = np.max(np.abs(r.C - Cs)) / np.max(np.abs(Cs))
    fe = r.undamped_freq_hz
    ef = np.max(np.abs(fe - fs) / fs) * 100 if np.all(np.isfinite(fe)) else np.inf
    pairs = {pp.analysis: pp.test for pp in pair_modes_by_mac(
        modal_assurance(np.asarray(r.mode_shapes), phi_s[:, inband]), 0.5)}

    def band_err(sel):
        e = [abs(r.natural_freq_hz[pairs[i]] - fs[m]) / fs[m] * 100
             for i, m in enumerate(inband) if m in sel and i in pairs]
        miss = sum(1 for i, m in enumerate(inband) if m in sel and i not in pairs)
        return (max(e) if e else np.inf), miss

    e_mid, m_mid = band_err(mid)
    e_low, m_low = band_err(low)
    if label == "noise-free":
        status = TargetRow("6", "full order, noise-free", "M, C, K within 0.03 %, frequencies 0.01 %",
                           f"M, C, K within {100 * max(em, ec):.2g} %, frequencies {ef:.2g} %",
                           "yes" if 100 * max(em, ec) <= 0.03 and ef <= 0.01 else "no")
    else:
        low_cell = (f"all {low.size} missed" if m_low == low.size else
                    f"{e_low:.3g} %" + (f" ({m_low} missed)" if m_low else ""))
        status = TargetRow("6", f"full order, {label}", "no solution",
                           f"in-band modes above 10 Hz {e_mid:.3g} %" + (f" ({m_mid} missed)" if m_mid else "")
                           + f"; suspension modes {low_cell}", "the report had none: ours stated")
    return (f"- ours, {label}: in-band modes {fs[mid[0]]:.3g}-{fs[mid[-1]]:.4g} Hz max frequency "
           f"error {fmt(e_mid, None, m_mid).strip()} %; suspension modes below 10 Hz "
           f"{fmt(e_low, None, m_low).strip()} %; M, K max entry error {100 * em:.3g} % of max "
           f"entry (C {100 * ec:.3g} %); all 16 undamped frequencies max error {ef:.3g} %"
           + ("" if not r.warnings else f"; warnings: {len(r.warnings)}") + cost), status


REACTION_NOTES = """- what we achieve where the report had no solution: noise-free, the substructure exactly.
  With the report's noise on accelerances, forces and reactions, the default finds every
  in-band mode above 10 Hz, to 0.9-2.1 % (rows above). Its step 1 (`ssid/step1_eiv.py`): SK
  with the equation-error covariance (reaction noise included) from the best of LS, TLS and
  scaled TLS by output error; where that stops above twice the number of equations (the
  cost's expected value at the true model), SK again from the other starts and from LS on the
  columns whose every accelerance's power is 4 times its noise or more, the lowest cost kept;
  then, twice, noise levels flat plus proportional per FRF re-estimated for accelerances and
  reactions at the fitted model (an EM step: each noise's conditional mean and variance given
  the equation error), and SK again. The lines below the noise (low frequencies, where the
  regressor h / w^2 is noise amplified by 1/w^2) bias the other starts most: from the best
  one by output error SK stopped at 130-150 times the true model's cost on seeds 1 and 3
  (5.7 % with a mode lost, 12.7 %), from the high-SNR start at 1.6 times (3.6 %, 3.8 %; seed
  2 stops at 1.9 times from its first start, 2.1 %). The re-estimated levels then give
  1.4 / 0.9 / 2.1 %; the costs printed are with those levels.
- what limits it (diagnosis on seed 1; errors in this note: the largest over the in-band modes
  above 10 Hz, each against the nearest identified frequency):
  - the search ends at 1.3-1.6 times the true model's cost, not in its minimum;
  - the noise levels: with one level per FRF (the roughness estimate, before the re-estimate),
    descending the cost from the true substructure (Gauss-Newton with the cost's exact
    gradient, not in the product) ended near 3.5 %, and with each value's own noise variance
    (known here from 60 other noise draws) near 0.65 %. Acquisition now records the
    variances of the averages for the reaction channels too (`H_reaction_var`), but the
    search from those variances (`report_noise_frf(..., with_variance=True)`) did worse: worst
    mode 4.3 / 0.5 / 2.9 / 22 % (7 modes lost) on seeds 1-4 against 1.4 / 0.9 / 2.1 / 0.5 %
    with levels estimated from the data, though it ended at a lower cost under the recorded
    variances on seeds 1-3; so with reactions the levels come from the data
    (docs/algorithm.md, known limits).
- tried and not adopted (seed 1 unless stated):
  - on seeds 1-3, each of the LS, TLS and scaled TLS starts refined with the reactions taken
    as exact (SK, then output error), then by SK with the full covariance, the lowest cost
    kept: seed 1 1.5 %; seed 3 21 % against 9.7 % then, at an eighth of its cost;
  - Gauss-Newton on the cost from the old estimate: cost 2.6e6 to 3.2e5 in 100 steps, 5.6 %;
  - bias-compensated LS (the regressors' noise covariance taken out of the normal matrix,
    with the true variances): the normal matrix comes out indefinite;
  - an output-error refinement with the reaction noise in its weights (an earlier stop): it
    lowered the cost and made the frequencies worse (4-11 %).
- not achieved: the three suspension modes (missed also by a free substructure without
  reactions under the same noise: not determined by these data) and M, K entry by entry (five
  modes above the band)."""
