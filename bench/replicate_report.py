"""Our versions of the report's chapter-6 experiments on our payload model, beside its figures.

    python bench/replicate_report.py [--quick] [--out docs/replication.md]

Each row prints the report's figure and ours. The error measure throughout is the largest
|percent error| over the target modes (natural frequency from the state-space roots, Eq. 5.19,
damping ratio Eq. 5.18), each identified mode paired one-to-one with a target mode by MAC at
the measured DOFs (Hungarian assignment, MAC >= 0.5; an unpaired target counts as a miss).
The report's figures are the largest |percent error| in its tables (read off the report).
Our payload model is not the report's (its section properties are not given: see
``ssid/models/payload.py``), so rows compare behaviour, not digits.

Noise: the report's ``addnoise`` (2 % magnitude of the FRF's RMS, 2 degree phase, uniform,
40 averages, on responses and forces), fixed seeds.
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import scipy.linalg as sla

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ssid.bands import overlapping_bands, process_bands, scale_selected_roots, strongest_roots  # noqa: E402
from ssid.correlate import (  # noqa: E402
    modal_assurance,
    pair_modes_by_mac,
    pair_modes_by_mac_and_frequency,
)
from ssid.frf import FRFData, accelerance_from_model, selection_matrix  # noqa: E402
from ssid.band_select import identify_mck_band_select, result_problems  # noqa: E402
from ssid.identify import identify_mck  # noqa: E402
from ssid.models.payload import (  # noqa: E402
    INTERFACE_DOFS,
    Z_DOFS,
    attach_test_stand,
    modal_damping,
    payload_simulator,
    rayleigh_damping,
    target_modes,
)
from ssid.noise import report_noise_frf  # noqa: E402
from ssid.placement import effective_independence  # noqa: E402
from ssid.pseudo_dof import (  # noqa: E402
    free_residue_error,
    frf_relative_error,
    identify_pseudo_dof,
    mck_accelerance,
    modal_model_accelerance,
    pseudo_dof_fit_error,
    pseudo_dof_mck,
    pseudo_modal_model,
)
from ssid.step1 import step1_data  # noqa: E402
from ssid.errors import IdentificationError  # noqa: E402
from ssid.tam import guyan_reduce  # noqa: E402

# The report's figures: largest |% error| over the target modes in each table column.
REPORT = {
    "full": "M, C, K within 0.25 %; all 52 frequencies to 8 digits",
    ("10", 300): (0.2376, 5.24), ("10", 650): (2.281, 41.83), ("10", 2100): (3.502, 368.1),
    ("12", 300): (2.570, 0.2125), ("12", 650): (3.353, 38.69), ("12", 2100): (1.979, 58.55),
    ("16", 300): (24.76, 11.26), ("16", 650): (14.0, 35.8), ("16", 2100): (0.6686, 29.64),
    ("noisy", "10", "tls"): (18.52, 736.8), ("noisy", "10", "stls"): (3.754, 81.03),
    ("noisy", "12", "tls"): (12.26, 212.8), ("noisy", "12", "stls"): (3.656, 241.1),
    ("noisy", "16", "any"): "no solution (M, K not positive definite) with LS, TLS or STLS",
    ("bands", "clean", "BP2"): 0.2202, ("bands", "clean", "BP3"): 6.893,
    ("bands", "noisy", "BP2"): 1.116, ("bands", "noisy", "BP3"): 23.42,
    "pseudo": "10-DOF, 1-2100 Hz: 20-DOF pseudo model finds 4 more target modes; step 2 unresolved",
    "reactions": "full order, noise-free: M, C, K within 0.03 %, frequencies 0.01 %; noisy: none",
}

#: Our spectra: the report's (Table 6.3), the third stretched to 2300 Hz so that our 16th
#: target mode (2200 Hz) is inside it, as the report's 16th (2031 Hz) was inside 2100 Hz.
SPECTRA = {300: (1.0, 300.0, 512), 650: (1.0, 650.0, 512), 2100: (1.0, 2300.0, 1024)}


class Truth:
    """The payload model, its modes and target modes."""

    def __init__(self) -> None:
        self.p = payload_simulator()
        self.C = modal_damping(self.p.M, self.p.K, 0.02)
        lam, self.phi = sla.eigh(self.p.K, self.p.M)
        self.f = np.sqrt(lam) / (2 * np.pi)
        self.iz = self.p.index(Z_DOFS)
        #: (n, f_max) -> whether the noise-free data gave an n-DOF modal model (section 2);
        #: section 3 skips the modal candidate where they did not (noise adds no modes).
        self.modal_possible: dict[tuple[int, float], bool] = {}

    def sensors(self, n: int) -> tuple[list[str], np.ndarray]:
        """EfI choice (Eq. 6.1) of n Z DOFs for the first n target modes; interface DOFs kept."""
        tm = target_modes(self.p, n)
        chosen = effective_independence(self.phi[self.iz][:, tm], n, Z_DOFS)
        for d in INTERFACE_DOFS:  # the report's inputs are at the interface: always measured
            if d not in chosen:
                worst = next(c for c in reversed(chosen) if c not in INTERFACE_DOFS)
                chosen[chosen.index(worst)] = d
        return [d for d in Z_DOFS if d in chosen], tm

    def frf(self, sensors, spectrum, inputs=INTERFACE_DOFS) -> FRFData:
        lo, hi, n = spectrum
        return accelerance_from_model(self.p.M, self.C, self.p.K, self.p.dofs,
                                      np.linspace(lo, hi, n), sensors, list(inputs))


def paired_errors(truth: Truth, sensors, tm, freq_hz, zeta, shapes) -> tuple[float, float, int]:
    """Largest |% error| of frequency and damping over targets paired by MAC x frequency
    ratio (MAC >= 0.5), and misses."""
    idx = truth.p.index(sensors)
    phi_t = truth.phi[idx][:, tm]
    mac = modal_assurance(np.asarray(shapes), phi_t)
    pairs = pair_modes_by_mac_and_frequency(mac, freq_hz, truth.f[tm], 0.5)
    if not pairs:
        return np.inf, np.inf, len(tm)
    ef = [abs(freq_hz[p.test] - truth.f[tm[p.analysis]]) / truth.f[tm[p.analysis]] for p in pairs]
    ez = [abs(zeta[p.test] - 0.02) / 0.02 for p in pairs]
    return 100 * max(ef), 100 * max(ez), len(tm) - len(pairs)


def modal_cell(truth: Truth, sensors, tm, cands: dict, f_hi: float) -> str:
    """The band-processed modal candidate's errors (``ssid.band_select.identify_mck_modal``),
    and the modes it holds that are not targets; or why there is none."""
    r = cands.get((f_hi, "bands"))
    if r is None:
        return "none (fewer modes than DOFs)"
    cell = fmt(*paired_errors(truth, sensors, tm, r.natural_freq_hz, r.damping_ratio,
                              r.mode_shapes))
    other = [f for f in r.natural_freq_hz
             if np.min(np.abs(truth.f[tm] - f) / truth.f[tm]) > 0.01]
    return cell + (f"; holds {', '.join(f'{f:.0f}' for f in other)} Hz" if other else "")


def fmt(e: float, z: float | None = None, miss: int = 0) -> str:
    s = f"{e:9.4g}" + (f" / {z:8.4g}" if z is not None else "")
    return s + (f" ({miss} missed)" if miss else "")


def full_order(truth: Truth) -> None:
    print("\n## 1. Full-order identification, noise-free (section 6.2.1)\n")
    p = truth.p
    frf = accelerance_from_model(p.M, truth.C, p.K, p.dofs, np.linspace(1, 15000, 128), p.dofs,
                                 ["4+Z", "17+RX", "18+RY"])
    t0 = time.perf_counter()
    r = identify_mck(frf, solver="ls")
    dt = time.perf_counter() - t0
    ef = np.max(np.abs(r.undamped_freq_hz - truth.f) / truth.f)
    em = [np.max(np.abs(A - B)) / np.max(np.abs(B)) for A, B in ((r.M, p.M), (r.C, truth.C), (r.K, p.K))]
    print("52 DOF, inputs 4+Z, 17+RX, 18+RY, 128 lines 1-15000 Hz, solver ls")
    print(f"- report: {REPORT['full']}")
    print(f"- ours: max |entry error| / max |entry|: M {em[0]:.1e}, C {em[1]:.1e}, K {em[2]:.1e}; "
          f"largest relative frequency error of the 52 modes {ef:.1e} ({dt:.1f} s)")


def reduced_noise_free(truth: Truth) -> None:
    print("\n## 2. Reduced-order models, noise-free, three input spectra (Tables 6.4-6.10)\n")
    print("frequency / damping max |% error| over the target modes: as in the report, the first "
          "n target modes at every spectrum, also those above the band (Tables 6.4-6.10 list them "
          "all). `default`: our default solver on the whole band. `band-selected`: "
          "`ssid.band_select.identify_mck_band_select`, band [f0, f_hi] (f_hi = f_max / sqrt(2)^k) and solver "
          "(ls, tls, stls, ml) chosen from the data alone: a physical model first, then the "
          "lowest noise-weighted output error of its M, C, K over all lines; one candidate is "
          "`modal (bands)`: `ssid.band_select.identify_mck_modal`, the n strongest modes with "
          "independent shapes found by band processing over the whole spectrum (bands of 1/12 "
          "of it, 50 % overlap, section 4's criteria), scaled by BP3 and assembled as real "
          "normal modes; it holds the modes the data show most strongly, not necessarily the "
          "report's target modes (those it holds instead are listed). `in band`: "
          "target modes inside the spectrum, ours / the report's (our model's modes sit "
          "elsewhere than the report's, so the same spectrum is not the same problem: the rows "
          "`(as 300 Hz)`, `(as 650 Hz)` use the spectrum that holds as many of our targets as "
          "the report's held of its own, with the next target as far above the edge "
          "(`equivalent_spectrum`).")
    jobs = [(n, label, key, spec) for n in ("10", "12", "16")
            for label, key, spec in spectra_for(truth, int(n))]
    rows = run_parallel(reduced_noise_free_row, jobs)
    for n in ("10", "12", "16"):
        sensors, tm = truth.sensors(int(n))
        print(f"\n{n}-DOF sensors (EfI): {', '.join(sensors)}; targets (Hz): "
              f"{', '.join(f'{truth.f[i]:.1f}' for i in tm)}\n")
        print("| model | spectrum | in band | report | ours, default | ours, modal (bands) | "
              "ours, band-selected | selected band, solver |")
        print("|---|---|---|---|---|---|---|---|")
        for (n_job, _, _, spec), (line, modal) in zip(jobs, rows):
            if n_job == n:
                truth.modal_possible[(int(n), spec[1])] = modal
                print(line)


def reduced_noise_free_row(n: str, label: str, key: int, spec) -> tuple[str, bool]:
    """One row of section 2, and whether the modal candidate existed (worker process)."""
    truth = worker_truth()
    sensors, tm = truth.sensors(int(n))
    frf = truth.frf(sensors, spec)
    cands: dict = {}
    r = identify_mck_band_select(frf, candidates=cands)
    full = float(frf.freq_hz[-1])
    d = cands[(full, "ml")]
    cells = [fmt(*paired_errors(truth, sensors, tm, x.natural_freq_hz, x.damping_ratio,
                                x.mode_shapes)) for x in (d, r)]
    cells.insert(1, modal_cell(truth, sensors, tm, cands, full))
    sel = r.info["band_select"]
    rep_t = np.asarray(REPORT_TARGETS_HZ[: int(n)])
    inb = f"{np.sum(truth.f[tm] <= spec[1])} / {np.sum(rep_t <= key)}"
    line = (f"| {n}-DOF | {label} | {inb} | {fmt(*REPORT[(n, key)])} "
            f"| {cells[0]} | {cells[1]} | {cells[2]} | 1-{r.band_hz[1]:.0f} Hz, {sel['solver']}"
            f"{'' if result_problems(r) == 0 else ' (not physical)'} |")
    return line, (full, "bands") in cands


_WORKER_TRUTH: Truth | None = None


def worker_truth() -> Truth:
    """The payload model, built once per process."""
    global _WORKER_TRUTH
    if _WORKER_TRUTH is None:
        _WORKER_TRUTH = Truth()
    return _WORKER_TRUTH


def run_parallel(fn, jobs: list[tuple]) -> list:
    """``[fn(*job) for job in jobs]`` on two processes (the machine's two cores), in order.

    The cases are independent and mostly small-matrix work that one BLAS thread serves
    as well as two, so each worker gets one thread: two cases at a time instead of one.
    """
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    saved = {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    os.environ.update({k: "1" for k in saved})
    try:
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
            return list(ex.map(fn, *zip(*jobs)))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def equivalent_spectrum(truth: Truth, n: int, key: int) -> tuple[float, float, int] | None:
    """Our spectrum that puts us where the report's ``key`` spectrum put it: as many of the
    first n targets in the band, and the first target above the band as far above the edge
    (the report's 300 Hz: 9 of 10 in band, the 10th at 1.015 x the edge, so its resonance
    peak is half in the band); where no edge does both (or all targets are in the band),
    the last target in the band as far below the edge. None where the report's spectrum
    already holds the same number on our model, or for the widest spectrum (all in band)."""
    rep_t = np.asarray(REPORT_TARGETS_HZ[:n])
    ours = truth.f[truth.sensors(n)[1]]
    lo, hi, lines = SPECTRA[key]
    k = int(np.sum(rep_t <= hi))
    if k == int(np.sum(ours <= hi)) or key == 2100:
        return None
    edges = ([ours[k] * hi / rep_t[k]] if k < n else []) + [ours[k - 1] * hi / rep_t[k - 1]]
    edge = next(e for e in edges if int(np.sum(ours <= e)) == k)
    return lo, float(np.round(edge)), lines


def spectra_for(truth: Truth, n: int) -> list[tuple[str, int, tuple[float, float, int]]]:
    """(label, report's spectrum key, our spectrum): the report's three, then the equivalents."""
    out = [(f"1-{spec[1]:g} Hz, {spec[2]} lines", key, spec) for key, spec in SPECTRA.items()]
    for key in SPECTRA:
        eq = equivalent_spectrum(truth, n, key)
        if eq is not None:
            out.append((f"1-{eq[1]:g} Hz, {eq[2]} lines (as {key} Hz)", key, eq))
    return out


#: The report's target modes (Table 6.1, asterisks), Hz: how many lie in each of its spectra.
REPORT_TARGETS_HZ = [1.1564, 6.0642, 10.783, 18.127, 109.49, 127.14, 137.82, 156.87, 297.66,
                     304.47, 606.45, 631.08, 1190.4, 1193.3, 2029.1, 2031.2]


def reduced_noisy(truth: Truth, seeds: list[int]) -> None:
    print("\n## 3. Noisy data: LS vs TLS vs scaled TLS vs our default (Tables 6.11-6.14)\n")
    print("frequency / damping max |% error| over target modes, worst over seeds "
          f"{seeds}; the report's spectrum per model (10-DOF 1-300 Hz, 12-DOF 1-650 Hz, 16-DOF "
          "1-2300 Hz here) and, as in section 2, the equivalent spectrum (`as ... Hz`). "
          "`band-selected` as in section 2 (its "
          "whole-band `ml` candidate is the `ml` row, its modal candidate the `bands` row, "
          "skipped where the noise-free data gave no modal model: noise adds no modes). "
          "`in band`: target modes in the spectrum, ours / the report's.")
    print("| model | spectrum | in band | solver | report | ours |")
    print("|---|---|---|---|---|---|")
    cases = []
    for n, key in (("10", 300), ("12", 650), ("16", 2100)):
        for label, spec in [(f"1-{SPECTRA[key][1]:g} Hz", SPECTRA[key])] + [
                (f"1-{eq[1]:g} Hz (as {key} Hz)", eq)
                for eq in [equivalent_spectrum(truth, int(n), key)] if eq is not None]:
            cases.append((n, key, label, spec))
    jobs = [(n, spec, seed, truth.modal_possible.get((int(n), spec[1]), True))
            for n, _, _, spec in cases for seed in seeds]
    results = iter(run_parallel(reduced_noisy_seed, jobs))
    for n, key, label, spec in cases:
        per_seed = [next(results) for _ in seeds]
        tm = truth.sensors(int(n))[1]
        inb = (f"{np.sum(truth.f[tm] <= spec[1])} / "
               f"{np.sum(np.asarray(REPORT_TARGETS_HZ[:int(n)]) <= key)}")
        for solver in per_seed[0][0]:
            res = max(errs[solver] for errs, _ in per_seed)
            if n == "16":
                rep = REPORT[("noisy", "16", "any")] if solver in ("ls", "tls", "stls") else "-"
            elif solver in ("tls", "stls"):
                rep = fmt(*REPORT[("noisy", n, solver)])
            else:
                rep = "no solution" if solver == "ls" else "-"
            extra = (f" ({'; '.join(chosen for _, chosen in per_seed)})"
                     if solver == "band-selected" else "")
            cell = fmt(*res) if np.isfinite(res[0]) else "no model (fewer modes than DOFs found)"
            print(f"| {n}-DOF | {label} | {inb} | {solver} | {rep} | {cell}{extra} |")
    print("\n" + REDUCED_NOTES)


def reduced_noisy_seed(n: str, spec, seed: int, modal: bool) -> tuple[dict, str]:
    """Errors of each solver and of the band search on one noisy record (worker process)."""
    truth = worker_truth()
    sensors, tm = truth.sensors(int(n))
    frf = report_noise_frf(truth.frf(sensors, spec), seed=seed)
    cands: dict = {}
    sel = identify_mck_band_select(frf, candidates=cands, modal=modal)
    chosen = (f"1-{sel.band_hz[1]:.0f} Hz {sel.info['band_select']['solver']}"
              + ("" if result_problems(sel) == 0 else " (not physical)"))
    full = float(frf.freq_hz[-1])
    errs = {}
    for solver in ("ls", "tls", "stls", "ml", "bands", "band-selected"):
        r = sel if solver == "band-selected" else cands.get((full, solver))
        errs[solver] = ((np.inf, np.inf, len(tm)) if r is None else  # no modal model
                        paired_errors(truth, sensors, tm, r.natural_freq_hz, r.damping_ratio,
                                      r.mode_shapes))
    return errs, chosen


REDUCED_NOTES = """Reading sections 2 and 3:

- **Same spectrum, different problem.** The report's 1-300 Hz held 9 of its 10 targets, with
  the 10th 1.5 % above the edge (its resonance half in the band); ours holds 7, and the 10th
  target (559 Hz) lies 1.9 times above the edge, so the 1-300 Hz rows ask our models to
  extrapolate much farther (in the 10-DOF default the in-band modes are within 0.07 %, the
  318.6 and 395.2 Hz targets above the band within 0.08 %, and the 559 Hz one 2.1 % off,
  which sets the row's 2.1 %). The `as 300 Hz`
  and `as 650 Hz` rows put our model where the report's spectra put its own.
- **The modal candidate** exists only when the band holds at least as many modes as the
  model has DOFs; it then holds those modes to the accuracy of band processing, and which
  modes it holds is the data's choice: at 12 and 16 Z sensors some rotation-dominated modes
  (754, 832, 1486, 1515, 1604 Hz) show more strongly than some targets, so targets count as
  missed although every mode the model holds is right.
- **Rounding.** The reduced-order `ml` fits whose band holds fewer modes than DOFs are
  ill-conditioned enough that the BLAS thread count changes them (10-DOF, 1-300 Hz: one
  thread 2.1 % / 15 %, a non-physical refinement replaced by its TLS start; two threads
  2.1 % / 3.1 %). This bench runs its cases two at a time with one BLAS thread each.
"""


BAND_NOTES = """Why M was not positive definite at first, and what changed (`ssid/bands.py`, `ssid/band_scaling.py`):

- **Kept roots with dependent shapes.** 22 modes are in 1-2300 Hz, the model holds 16. The
  payload is symmetric about x = 30 in: at the 16 Z sensors the symmetric modes span 8
  dimensions and the antisymmetric 8. The strongest 16 roots held 9+ of one kind, so the mode
  matrix of Eq. 3.26 was singular (cond 3e14) and no M exists whatever the scale factors.
  `strongest_roots` now keeps only roots whose shapes are independent (and takes roots an
  analyst paired with target modes first, `prefer=`); `scale_selected_roots` refuses a
  dependent set. Picked automatically, the independent set still holds non-target (rotation
  dominated) modes, hence 26.7 % in the "auto" rows: which 16 of 22 modes a 16-DOF model
  should hold is the analyst's choice, as in the report (its roots were picked by hand).
- **Residual modes in Eq. 3.23.** Fitting the scale factors with only the kept modes forced
  the tails of the others onto them (errors up to 20 % for BP2, 70 % for BP3, 0.4 % on the
  frequencies). The fit now has real residual terms (mass line, static compliance) per band,
  window or run of lines; BP1/BP2 use all roots of their band, BP3 all roots that passed the
  criteria.
- **State-space inverse on noisy broad-band data.** Eq. 3.26 through the full inverse gives
  `M = (M^-1 + X K X)^-1` with `X = Theta_x diag(u) Theta_x^T`, zero for exact modes; the
  slightly complex shapes of noisy bands (X of 2e-5 of M^-1) times the stiffness of modes
  three decades above the lowest make M indefinite, even with the exact scale factors. The
  `normal` assembly (`normal_mode_mck`) takes the modes as real normal modes (what the MPC
  criterion checks): X = 0, M and K are positive definite when every modal mass is positive,
  and eig(K, M) = |lambda_r|^2, so its frequency error is the root error.

- **Repeat tolerance and the line spacing (criterion 4).** A root is located to a fraction of
  the width over which the lines see it: its half-power band 2 zeta f when the lines resolve
  it, the line spacing df when they do not. The tolerance is now 1/8 of max(2 zeta f, df)
  (0.5 % of f, as before, for a resolved 2 %-damped mode; `repeat_tolerance_hz`): the 1.29 Hz
  suspension mode (2 zeta f = 0.05 Hz, df = 2.25 Hz), whose estimates in bands 0 and 1
  differ by 1.4 % of f (0.8 % of df), is kept; lightly damped noise roots get a tighter
  tolerance than before. Pairs are matched closest first, one root per band, so a noise
  root beside a mode does not take its place, and a mode's representative is the estimate
  farthest from a band edge inside the record.
- **BP3 scale factors from each root's own lines.** Far above a mode, its tail is its mass
  line (absorbed by the residual terms) plus j w 2 Re(u theta theta^T), zero for a normal
  mode and set by the slight complexity of noisy shapes. Fitted on every run, the hundreds of
  lines far above the 1-6 Hz modes set their scale factors through that term (modal masses
  40-300 times off, some negative): in BP3 a root now gets equations only from the runs that
  hold its resonance, while every run's model keeps all roots (exact on noise-free data).
  The residual terms are dropped in a run holding a mode narrower than the line spacing,
  whose mass line they would otherwise take (`residual_runs`; here the 1-12 Hz run).

Still open: with the report's noise the 1.29 Hz mode is not always kept: seed 2 rejects its
band-0 estimate by MPC (0.74 < 0.8), so it is not repeated (16/16 targets with seeds 1 and 3,
15/16 with seed 2); and noise roots found in the lines two bands share (563.9 Hz, seed 3) are
repeated by construction, which criterion 4 cannot reject. The state-space assembly (Eq. 3.26
through the full inverse) stays indefinite on noisy data (see above).
"""


def band_processing(truth: Truth, seed: int, width_hz: float) -> None:
    # Local import: the module's import block is shared with other sections' edits.
    from ssid.errors import IdentificationError

    print("\n## 4. Band processing, 16-DOF, 1-2300 Hz (Tables 6.15-6.17)\n")
    sensors, tm = truth.sensors(16)
    idx = truth.p.index(sensors)
    clean = truth.frf(sensors, SPECTRA[2100])
    bands = overlapping_bands(1.0, 2300.0, width_hz, 0.5)
    print(f"{len(bands)} bands of {width_hz:g} Hz, 50 % overlap; MPC >= 0.8. The data hold "
          f"{int(np.sum(truth.f < 2300))} modes, the 16-DOF model 16: the roots kept are either the "
          "strongest with independent shapes (auto) or first those paired by MAC with the "
          "target modes, as the report picked its roots by hand (target), then the strongest "
          "independent ones. Criterion 4 tolerance 1/8 of max(2 zeta f, df). Scale factors with "
          "residual terms (none in a run holding a mode narrower than the line spacing; BP3 "
          "fits each root on the runs holding its resonance); M, C, K by Eq. 3.26 (state "
          "space, the report's) or as real normal modes (normal). Cells: max |% error| of the "
          "undamped frequencies of the assembled M, C, K (eig(K, M)) over the 16 target modes, "
          "each against the nearest identified one.")
    print("| data | roots kept | selected roots | targets found | BP2 report | BP2 state space | "
          "BP2 normal | BP3 report | BP3 state space | BP3 normal |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, frf, solver in (("clean", clean, "ls"),
                               ("noisy", report_noise_frf(clean, seed=seed), "ml")):
        res = process_bands(frf, bands, solver=solver)
        sel_f = res.freq_hz
        found = sum(np.min(np.abs(sel_f - truth.f[i])) / truth.f[i] < 0.01 for i in tm)
        e_sel = max(np.min(np.abs(sel_f - truth.f[i])) / truth.f[i] for i in tm) * 100
        shapes = np.column_stack([r.theta[: len(sensors)] for r in res.selected])
        pairs = pair_modes_by_mac(modal_assurance(shapes, truth.phi[idx][:, tm]), 0.5)
        paired = [p.test for p in pairs]
        for how, prefer in (("auto", None), ("target", paired)):
            kept = strongest_roots(frf, res, len(sensors), prefer=prefer)
            cells = []
            for m in ("BP2", "BP3"):
                for assembly in ("state-space", "normal"):
                    try:
                        _, mck = scale_selected_roots(frf, kept, m, assembly=assembly)
                    except IdentificationError as exc:
                        cells.append(f"no M ({exc})"[:40])
                        continue
                    if mck is None:
                        cells.append(f"{len(kept.selected)} roots kept")
                    elif np.linalg.eigvalsh(mck[0]).min() <= 0:
                        cells.append("M not positive definite")
                    else:
                        fu = np.sqrt(np.abs(sla.eigh(mck[2], mck[0], eigvals_only=True))) / (2 * np.pi)
                        err = [np.min(np.abs(fu - truth.f[i])) / truth.f[i] * 100 for i in tm]
                        hit = [e for e, i in zip(err, tm)
                               if np.min(np.abs(sel_f - truth.f[i])) / truth.f[i] < 0.01]
                        cells.append(f"{max(err):.3g}" + ("" if len(hit) == len(tm) else
                                     f" ({max(hit):.3g} over the {len(hit)} found)"))
            print(f"| {label} | {how} | {sel_f.size} | {found}/16 (max err {e_sel:.3g} %) | "
                  f"{REPORT[('bands', label, 'BP2')]} | {cells[0]} | {cells[1]} | "
                  f"{REPORT[('bands', label, 'BP3')]} | {cells[2]} | {cells[3]} |")
    print("\n" + BAND_NOTES)


def pseudo_dof(truth: Truth) -> None:
    print("\n## 5. Pseudo degrees of freedom, 10-DOF, 1-2100 Hz, 1024 lines (Table 6.18)\n")
    sensors, _ = truth.sensors(10)
    frf = truth.frf(sensors, (1.0, 2100.0, 1024))
    r10 = identify_mck(frf, solver="ls")
    res = identify_pseudo_dof(frf)
    tm = target_modes(truth.p, 16)
    tf = truth.f[tm]

    def found(freqs):
        return [f"{truth.f[i]:.0f}" for i in tm if np.min(np.abs(np.asarray(freqs) - truth.f[i])) < 0.01 * truth.f[i]]

    print(f"- report: {REPORT['pseudo']}")
    print(f"- ours, original 10-DOF model: targets found within 1 %: {', '.join(found(r10.natural_freq_hz))}")
    print(f"- ours, 20-DOF pseudo model, roots flagged structural by the partition-consistency "
          f"indicator: {', '.join(f'{f:.1f}' for f in res.freq_hz[res.structural])}")
    print(f"  targets found within 1 %: {', '.join(found(res.freq_hz[res.structural]))} "
          f"(of {', '.join(f'{f:.0f}' for f in tf[tf <= 2100])} in the band)")
    print(f"  rejected as computational: {', '.join(f'{f:.1f}' for f in res.freq_hz[~res.structural])}")
    print(f"- previous step 2 attempt (pseudo DOFs as generalised coordinates): relative RMS FRF "
          f"error {100 * pseudo_dof_fit_error(frf, res):.1f} % with the structural roots, "
          f"{100 * pseudo_dof_fit_error(frf, res, False):.1f} % with all roots; no physical M, C, K")
    # Step 2 on the measured FRFs: structural roots, measured-partition shapes, Eq. 3.23 fit
    # of the scale factors on all lines with residual terms. FRF errors are relative RMS over
    # all 1024 lines x 10 outputs x 3 inputs.
    mm = pseudo_modal_model(frf, res)
    d = step1_data(frf)
    bound = free_residue_error(frf, mm.lam)
    e_modal = frf_relative_error(modal_model_accelerance(mm, frf.omega, residual_fit=d), frf.H)
    bad = mm.freq_hz[~mm.physical]
    print(f"- step 2, modal model (structural roots, shapes = the partition carrying each root, "
          f"Eq. 3.23 scale factors with residual terms, all lines): FRF error {100 * e_modal:.1f} %; "
          f"best possible with these roots and free residues: {100 * bound:.1f} % (the rest is "
          f"the in-band modes the pseudo model did not find)")
    print(f"  modal mass <= 0 (not a passive mode, left out of M, C, K): "
          f"{', '.join(f'{f:.1f}' for f in bad) or 'none'} Hz")
    for label, n_keep in (("all modes with m_r > 0, measured DOFs + generalised coordinates", None),
                          ("reduced, the 10 strongest independent modes", 10)):
        try:
            g = pseudo_dof_mck(frf, mm, n_keep)
        except IdentificationError as exc:  # report, do not stop the other sections
            print(f"- M, C, K, {label}: none ({exc})")
            continue
        Hg = mck_accelerance(g.M, g.C, g.K, frf.omega, g.n_measured, frf.input_index())
        ok_m = np.linalg.eigvalsh(g.M).min() > 0
        ok_k = np.linalg.eigvalsh(g.K).min() >= 0
        print(f"- M, C, K, {label}: {g.M.shape[0]} DOF, FRF error "
              f"{100 * frf_relative_error(Hg, frf.H):.1f} %, M > 0: {ok_m}, K >= 0: {ok_k}; "
              f"eig(K, M): {', '.join(f'{f:.1f}' for f in g.undamped_freq_hz)} Hz")
        print(f"  targets found within 1 %: {', '.join(found(g.undamped_freq_hz))}")


def reactions(truth: Truth, seeds: list[int]) -> None:
    print("\n## 6. Reaction forces: substructure on three 9-DOF test stands (section 6.6)\n")
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
    print("16-DOF Guyan substructure; coupled 25-DOF Guyan model with Rayleigh damping; inputs "
          "at 11+Z and 16+Z; reactions at 4+Z, 8+Z, 18+Z; 512 lines 1-1000 Hz; substructure "
          f"modes in the band: {inband.size} of 16 ({fs[inband[0]]:.3g}-{fs[inband[-1]]:.4g} Hz)")
    print(f"- report: {REPORT['reactions']}")
    for label, data in [("noise-free", frf)] + [(f"noisy seed {s}", report_noise_frf(frf, seed=s)) for s in seeds]:
        r = identify_mck(data)
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
        print(f"- ours, {label}: in-band modes {fs[mid[0]]:.3g}-{fs[mid[-1]]:.4g} Hz max frequency "
              f"error {fmt(e_mid, None, m_mid).strip()} %; suspension modes below 10 Hz "
              f"{fmt(e_low, None, m_low).strip()} %; M, K max entry error {100 * em:.3g} % of max "
              f"entry (C {100 * ec:.3g} %); all 16 undamped frequencies max error {ef:.3g} %"
              + ("" if not r.warnings else f"; warnings: {len(r.warnings)}"))
    print("- what we achieve where the report had no solution: noise-free, the substructure exactly. "
          "With the report's noise on accelerances, forces and reactions, the default (SK with the "
          "equation-error covariance, which includes the reaction noise, then output-error ML) "
          "finds the in-band modes above 10 Hz to a few % (rows above), not to the ~0.3 % that "
          "the cost minimum next to the true model holds (seed 1, found from the true model for "
          "diagnosis only): the optimisation stops short of that minimum. An output-error "
          "refinement with the reaction noise in its weights was tried; it lowered the cost but "
          "made the frequencies worse (4-11 %), which points at the noise weights, and was not "
          "adopted. Not achieved: the three suspension modes (tens of % off even at that "
          "minimum, and missed by a free substructure without reactions under the same noise: "
          "not determined by these data) and M, K entry by entry (five modes above the band).")

def section_6_5(truth: Truth) -> None:
    print("\n## 7. SSID models against TAMs (section 6.5, Tables 6.21-6.26)\n")
    from replicate_tams import replicate_section_6_5

    sets = {f"{n}-DOF": truth.sensors(n)[0] for n in (10, 12, 16)}
    targets = {f"{n}-DOF": [int(i) + 1 for i in truth.sensors(n)[1]] for n in (10, 12, 16)}
    print("```")
    print(replicate_section_6_5(truth.p.M, truth.p.K, truth.C, truth.p.dofs, INTERFACE_DOFS,
                                sets, target_modes=targets))
    print("```")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one noise seed, wider bands")
    ap.add_argument("--out", help="also write the tables (markdown) to this file")
    args = ap.parse_args()
    seeds = [1] if args.quick else [1, 2, 3]
    truth = Truth()
    buf = io.StringIO()
    t0 = time.perf_counter()

    class Tee(io.TextIOBase):
        def write(self, s):
            sys.__stdout__.write(s)
            buf.write(s)
            return len(s)

    with redirect_stdout(Tee()):
        print("# Replication of the report's chapter 6 on our payload model\n")
        print("Regenerate: `python bench/replicate_report.py --out docs/replication.md`")
        took = []
        for section, section_args in ((full_order, ()), (reduced_noise_free, ()),
                                      (reduced_noisy, (seeds,)),
                                      (band_processing, (seeds[0], 400.0 if args.quick else 200.0)),
                                      (pseudo_dof, ()), (reactions, (seeds,)), (section_6_5, ())):
            t1 = time.perf_counter()
            section(truth, *section_args)
            took.append(f"{section.__name__} {time.perf_counter() - t1:.0f} s")
        print(f"\n(total {time.perf_counter() - t0:.0f} s: {', '.join(took)})")
    if args.out:
        Path(args.out).write_text(buf.getvalue(), encoding="utf-8")


if __name__ == "__main__":
    main()
