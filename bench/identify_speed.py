"""How the time and memory of ``identify_mck`` grow with lines, DOFs and inputs.

Three sweeps around a base case (52 DOF, 3 inputs, 1024 lines), one factor at a time:

* frequency lines 128 ... 8192 (52 DOF, 3 inputs),
* DOFs 10 ... 100 (3 inputs, 1024 lines),
* inputs 1 ... 3 (52 DOF, 1024 lines).

Each case is a seeded, non-proportionally damped chain (``chain_model``, built like
``example_system`` for any n) with noise-free accelerances at every DOF over a band that covers
all its modes. For each case and solver ("ls", "ml") the table gives:

* ``svd_s``: best time of ONE ``np.linalg.svd(A, full_matrices=False)`` of the step-1 data
  matrix ``A = [Re Z; Im Z]`` (2 L n_in rows, 2n + n_in columns), built as
  ``ssid.step1.estimate_equation_error`` builds it; measured in the same process, just before
  the identification, so that the ratio sees the same machine state;
* ``id_s`` and ``id/svd``: best time of ``identify_mck(frf, solver=...)`` and its ratio;
* ``path``: for "ml", ``ML`` (maximum-likelihood refinement) or ``LW`` (the line-weighted
  path taken when n (2n + n_in) > ssid.step1_ml.ML_MAX_UNKNOWNS, ``info["ml_skipped"]``);
* ``peak_MB``: tracemalloc peak of the identification (the FRF data exist before it starts);
* ``LnIS_MB``: 16 L n n_in 2n bytes, what a complex array over lines x outputs x inputs x
  states would take, to show the memory does not follow that product;
* ``max_df/f``: largest relative error of the identified natural frequencies against the
  true complex eigenvalues (``|lambda| / 2 pi``); ``[m/n]`` flags a different mode count.

Each case runs in its own worker process, so a case that exceeds ``--timeout`` seconds is
killed and reported as "skipped (too slow)" instead of hanging the run; a full-ML case whose
time, extrapolated from a smaller measured full-ML case, exceeds 1.5 timeouts is not started
(the estimate is printed).

Run:  python bench/identify_speed.py [--quick] [--threads N] [--timeout 60] [--solvers ls,ml]
      [--profile]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import selectors
import subprocess
import sys
import time

BASE = {"n": 52, "n_in": 3, "lines": 1024}
FULL = {
    "lines": [128, 256, 512, 1024, 2048, 4096, 8192],
    "n": [10, 20, 30, 52, 75, 100],
    "n_in": [1, 2, 3],
}
QUICK = {
    "lines": [256, 1024, 4096],
    "n": [10, 20, 52],
    "n_in": [1, 3],
}
SWEEP_TITLE = {
    "lines": "frequency lines (52 DOF, 3 inputs)",
    "n": "DOFs (3 inputs, 1024 lines)",
    "n_in": "inputs (52 DOF, 1024 lines)",
}
SVD_REPS = 5
ID_REPS = 3
#: Time allowed to a worker for its setup (imports, test system, FRFs) and first SVD.
SETUP_S = 120.0
#: A full-ML case whose extrapolated time exceeds this many timeouts is not started.
PRE_SKIP = 1.5
#: Stop repeating an identification once the repetitions so far took this long (s).
REP_BUDGET_S = 4.0


# ----------------------------------------------------------------------------------------------
# The test system


def bench_system(n: int, seed: int = 1, decades: float = 2.0):
    """M, C, K, dofs of a chain like ``example_system`` with n masses, modes over ~``decades``.

    Masses 0.5-2 kg, springs graded from stiff to soft along the chain, springs to ground at
    both ends, two cross springs, and dampers placed unlike the springs (non-proportional
    damping, ratios of about 0.2-6 %). The soft end of the spring grade is tuned (bisection on
    its log) so the modes span about ``decades`` decades for every n.
    """
    import numpy as np

    from ssid.modal import complex_modes
    from ssid.models.lumped import chain_model

    def build(k_lo):
        rng = np.random.default_rng(seed)
        m = rng.uniform(0.5, 2.0, n)
        kb = np.geomspace(4e6, k_lo, n - 1) * rng.uniform(0.7, 1.3, n - 1)
        kg = np.zeros(n)
        kg[0], kg[-1] = 6e4, 2e4
        cb = rng.uniform(0.2, 1.0, n - 1) * np.sqrt(kb * m[:-1]) * 0.06
        cg = np.zeros(n)
        cg[n // 2] = 20.0
        extra = [(1, n // 2, 3e4), (n // 3, n - 2, 1e4)]
        return chain_model(m, kb, kg, cb, cg, extra)

    def spread(k_lo):
        M, C, K, _ = build(k_lo)
        f = np.abs(complex_modes(M, C, K)[0])
        return np.log10(f[-1] / f[0])

    lo, hi = np.log10(4e2), np.log10(4e6)  # soft end: 4e2 (wide spread) .. 4e6 (no grade)
    for _ in range(30):
        mid = (lo + hi) / 2
        if spread(10**mid) > decades:
            lo = mid
        else:
            hi = mid
    return build(10 ** ((lo + hi) / 2))


def bench_case(n: int, n_in: int, lines: int):
    """(frf, true natural frequencies in Hz) of one case: all DOFs measured, spread inputs."""
    import numpy as np

    from ssid.frf import accelerance_from_model
    from ssid.modal import complex_modes

    M, C, K, dofs = bench_system(n)
    f_true = np.abs(complex_modes(M, C, K)[0]) / (2 * np.pi)
    freq = np.linspace(0.5 * f_true[0], 1.3 * f_true[-1], lines)
    at = np.linspace(0, n - 1, n_in + 2).round().astype(int)[1:-1]
    inputs = [dofs[i] for i in at]
    return accelerance_from_model(M, C, K, dofs, freq, dofs, inputs), f_true


# ----------------------------------------------------------------------------------------------
# Worker: one case in its own process, results as JSON lines on stdout


def _emit(**kw) -> None:
    sys.stdout.write(json.dumps(kw) + "\n")
    sys.stdout.flush()


def worker(n: int, n_in: int, lines: int, solvers: list[str]) -> None:
    import tracemalloc

    import numpy as np

    from ssid.identify import identify_mck
    from ssid.step1 import step1_data, step1_regressors
    from ssid.step1_ml import ML_MAX_UNKNOWNS

    frf, f_true = bench_case(n, n_in, lines)

    # The step-1 data matrix exactly as estimate_equation_error builds it (line weights 1).
    d = step1_data(frf)
    Z = step1_regressors(d, d.H)
    ok = d.col_ok
    Zc = Z[ok] * np.ones(ok.shape)[ok][:, None]
    A = np.vstack([Zc.real, Zc.imag])

    def svd_baseline() -> None:
        times = []
        for _ in range(SVD_REPS):
            t0 = time.perf_counter()
            np.linalg.svd(A, full_matrices=False)
            times.append(time.perf_counter() - t0)
            if sum(times) > 2.0:
                break
        _emit(stage="svd", shape=list(A.shape), svd_s=min(times))

    # The baseline is measured before and after every identification; the parent keeps the
    # best, so a burst of load from elsewhere spoils neither number alone.
    del Z, Zc, d
    svd_baseline()

    for solver in solvers:
        times, traced_time, peak, res = [], None, None, None
        for rep in range(ID_REPS + 1):
            traced = rep == 0  # first run: memory (and warm-up); tracemalloc costs little here
            if traced:
                tracemalloc.start()
            t0 = time.perf_counter()
            res = identify_mck(frf, solver=solver)
            dt = time.perf_counter() - t0
            if traced:
                peak = tracemalloc.get_traced_memory()[1]
                tracemalloc.stop()
                traced_time = dt
                _emit(stage="progress", solver=solver, first_s=dt)
            else:
                times.append(dt)
            if traced_time + sum(times) > REP_BUDGET_S:
                break
        f_id = np.asarray(res.natural_freq_hz)
        m = min(f_id.size, f_true.size)
        err = float(np.max(np.abs(f_id[:m] - f_true[:m]) / f_true[:m])) if m else float("nan")
        path = "-"
        if solver == "ml":
            path = "LW" if "ml_skipped" in res.info else "ML"
        _emit(
            stage="id",
            solver=solver,
            id_s=min(times) if times else traced_time,
            traced_only=not times,
            reps=len(times) + 1,
            peak_mb=peak / 1e6,
            path=path,
            unknowns=n * (2 * n + n_in),
            ml_max=ML_MAX_UNKNOWNS,
            err=err,
            modes=[int(f_id.size), int(f_true.size)],
        )
        svd_baseline()


# ----------------------------------------------------------------------------------------------
# Parent: run workers with a time limit, print tables


THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_case(case: tuple[int, int, int], solvers: list[str], timeout: float,
             threads: int | None = None) -> dict:
    """Run one case's worker; kill it if a stage exceeds ``timeout``. Returns parsed results."""
    n, n_in, lines = case
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", str(n), str(n_in), str(lines),
           "--solvers", ",".join(solvers)]
    env = dict(os.environ)
    if threads:
        env.update({k: str(threads) for k in THREAD_VARS})
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    out: dict = {"id": {}, "timed_out": None, "error": None}
    pending = list(solvers)
    # Stage limit: the data/SVD stage gets ``timeout``; each solver's first run gets ``timeout``
    # and its few extra repetitions (bounded by REP_BUDGET_S in the worker) a little more.
    deadline = time.monotonic() + max(timeout, SETUP_S)  # imports, system, FRFs, first SVD
    while True:
        left = deadline - time.monotonic()
        if left <= 0 or not sel.select(timeout=left):
            proc.kill()
            proc.wait()
            out["timed_out"] = pending[0] if pending and "svd" in out else "svd"
            break
        line = proc.stdout.readline()
        if not line:
            break
        rec = json.loads(line)
        if rec["stage"] == "svd":
            if "svd" not in out or rec["svd_s"] < out["svd"]["svd_s"]:
                out["svd"] = rec
            deadline = time.monotonic() + timeout
        elif rec["stage"] == "progress":
            deadline = time.monotonic() + REP_BUDGET_S + rec["first_s"] + 10.0
        elif rec["stage"] == "id":
            out["id"][rec["solver"]] = rec
            pending.remove(rec["solver"])
            deadline = time.monotonic() + timeout
    if proc.poll() is None:
        proc.wait()
    err = proc.stderr.read()
    if proc.returncode not in (0, None) and out["timed_out"] is None:
        out["error"] = (err.strip().splitlines() or ["worker failed"])[-1]
    sel.close()
    return out


def predict_ml_full(case, measured: dict) -> tuple[float, tuple] | None:
    """Time of the full ML path extrapolated from the largest measured full-ML case.

    Its cost is dominated by the (n p)^2 normal matrix: assembled in O(L n_in (n p)^2) and
    solved in O((n p)^3) per iteration. Measured here between 20 and 30 DOF the time grows as
    about (n p)^2.5 at fixed L n_in, which is the model used. Cases under 1 s are dominated by
    fixed costs and are not used as references (they would extrapolate wildly).
    """
    refs = [(c, r) for c, r in measured.items() if r.get("path") == "ML" and r["id_s"] >= 1.0]
    if not refs:
        return None
    (rn, rin, rl), r = max(refs, key=lambda cr: cr[0][0] * (2 * cr[0][0] + cr[0][1]))
    n, n_in, lines = case
    u, ru = n * (2 * n + n_in), rn * (2 * rn + rin)
    scale = (lines * n_in) / (rl * rin) * (u / ru) ** 2.5
    return r["id_s"] * scale, (rn, rin, rl)


def machine_header() -> str:
    import numpy as np
    import scipy

    parts = [
        f"python {platform.python_version()}",
        f"numpy {np.__version__}",
        f"scipy {scipy.__version__}",
        f"{platform.machine()}",
        f"cpus {os.cpu_count()} (usable {len(os.sched_getaffinity(0))})"
        if hasattr(os, "sched_getaffinity") else f"cpus {os.cpu_count()}",
    ]
    blas = getattr(np.__config__, "CONFIG", {}).get("Build Dependencies", {}).get("blas", {})
    if blas:
        parts.append(f"BLAS {blas.get('name')} {blas.get('version')}")
    try:
        from threadpoolctl import threadpool_info

        for p in threadpool_info():
            parts.append(f"{p.get('internal_api')} threads={p.get('num_threads')}")
    except ImportError:
        env = {k: os.environ[k] for k in THREAD_VARS if k in os.environ}
        parts.append("threadpoolctl not installed; thread env: " + (str(env) if env else "unset"))
    parts.append(load_avg())
    return "# " + " | ".join(parts) + "\n# ssid source: " + source_version()


def load_avg() -> str:
    try:
        return "load avg {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except (OSError, AttributeError):
        return "load avg n/a"


def source_version() -> str:
    """Git commit of the checkout and whether ssid/ has uncommitted changes (timings move with
    the library, so a table is only comparable with another of the same source)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        head = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10, check=False).stdout.strip()
        dirty = subprocess.run(["git", "-C", root, "status", "--porcelain", "--", "ssid"],
                               capture_output=True, text=True, timeout=10,
                               check=False).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown (no git)"
    return f"{head or 'unknown'}{' + uncommitted changes in ssid/' if dirty else ''}"


def cpu_busy(dt: float = 1.0) -> float | None:
    """Fraction of all cores busy over ``dt`` seconds, from /proc/stat (None elsewhere)."""

    def sample():
        with open("/proc/stat") as fh:
            v = [int(x) for x in fh.readline().split()[1:]]
        return sum(v), v[3] + v[4]  # total, idle + iowait

    try:
        t0, i0 = sample()
        time.sleep(dt)
        t1, i1 = sample()
    except (OSError, ValueError, IndexError):
        return None
    return 1.0 - (i1 - i0) / max(t1 - t0, 1)


COLS = (f"{'value':>6} {'solver':>6} {'path':>4} {'A rows x cols':>14} {'svd_s':>8} {'id_s':>8} "
        f"{'id/svd':>8} {'peak_MB':>8} {'LnIS_MB':>9} {'max_df/f':>9}")


def fmt_row(value, solver, svd, rec, note=None) -> str:
    shape = f"{svd['shape'][0]}x{svd['shape'][1]}" if svd else "?"
    svd_s = f"{svd['svd_s']:8.4f}" if svd else f"{'?':>8}"
    head = f"{value:>6} {solver:>6}"
    if rec is None:
        return f"{head} {'':>4} {shape:>14} {svd_s} {note}"
    t = f"{rec['id_s']:8.3f}" + ("*" if rec["traced_only"] else "")
    ratio = f"{rec['id_s'] / svd['svd_s']:8.1f}" if svd else f"{'?':>8}"
    mf, mt = rec["modes"]
    err = f"{rec['err']:9.1e}" + ("" if mf == mt else f" [{mf}/{mt}]")
    return f"{head} {rec['path']:>4} {shape:>14} {svd_s} {t:>8} {ratio} {rec['peak_mb']:8.1f} " \
           f"{rec['lnis_mb']:9.1f} {err}"


def profile_base(solvers: list[str], top: int = 12) -> None:
    """cProfile of one identification per solver in the base case (after a warm-up run)."""
    import cProfile
    import io
    import pstats

    from ssid.identify import identify_mck

    frf, _ = bench_case(BASE["n"], BASE["n_in"], BASE["lines"])
    for solver in solvers:
        identify_mck(frf, solver=solver)
        prof = cProfile.Profile()
        prof.enable()
        identify_mck(frf, solver=solver)
        prof.disable()
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(top)
        body = [ln for ln in buf.getvalue().splitlines() if ln.strip()]
        print()
        print(f"== profile: solver {solver!r}, base case, top {top} functions by own time")
        print("\n".join(ln for ln in body if not ln.lstrip().startswith(("Ordered", "List"))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sweep (a minute or so)")
    ap.add_argument("--timeout", type=float, default=60.0,
                    help="seconds one identification may take before it is skipped (default 60)")
    ap.add_argument("--solvers", default="ls,ml", help="comma-separated (default ls,ml)")
    ap.add_argument("--threads", type=int, default=None,
                    help="BLAS threads in the workers (sets OPENBLAS/OMP/MKL_NUM_THREADS); "
                         "default: as the environment says. 1 is steadier on a shared machine")
    ap.add_argument("--profile", action="store_true",
                    help="also print where the time goes (cProfile, top functions) in the base case")
    ap.add_argument("--profile-worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--worker", nargs=3, type=int, metavar=("N", "N_IN", "LINES"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    solvers = [s for s in args.solvers.split(",") if s]
    if args.worker:
        worker(*args.worker, solvers)
        return
    if args.profile_worker:
        profile_base(solvers)
        return

    import numpy as np  # noqa: F401 - version for the header

    from ssid.step1_ml import ML_MAX_UNKNOWNS

    sweeps = QUICK if args.quick else FULL
    print(machine_header())
    if args.threads:
        print(f"# workers run with {', '.join(THREAD_VARS)} = {args.threads}")
    print(f"# sweep: {'quick' if args.quick else 'full'}; base case {BASE['n']} DOF, "
          f"{BASE['n_in']} inputs, {BASE['lines']} lines; timeout {args.timeout:g} s per "
          f"identification; ML_MAX_UNKNOWNS = {ML_MAX_UNKNOWNS}")
    busy = cpu_busy()
    if busy is not None:
        print(f"# CPU busy before start (1 s sample, all cores): {100 * busy:.0f} %")
        if busy > 0.2:
            print("# WARNING: other processes compete for the cores; timings will be inflated and "
                  + ("noisy" if args.threads == 1 else
                     "noisy, multi-threaded BLAS worst (try --threads 1, see bench/README.md)"))
    print(f"# times: best of up to {ID_REPS + 1} runs (first run under tracemalloc; '*' = that "
          "run only, case too slow to repeat)")
    t_start = time.perf_counter()
    results: dict = {}  # case -> run_case output
    ml_measured: dict = {}  # case -> ml record, for extrapolation
    for key in ("lines", "n", "n_in"):
        print()
        print(f"== sweep: {SWEEP_TITLE[key]}")
        print(COLS)
        for v in sweeps[key]:
            case = dict(BASE, **{key: v})
            c = (case["n"], case["n_in"], case["lines"])
            if c not in results:
                run_solvers, pre_skip = list(solvers), {}
                if "ml" in run_solvers and c[0] * (2 * c[0] + c[1]) <= ML_MAX_UNKNOWNS:
                    pred = predict_ml_full(c, ml_measured)
                    if pred and pred[0] > PRE_SKIP * args.timeout:
                        run_solvers.remove("ml")
                        pre_skip["ml"] = (f"skipped (too slow): est. {pred[0]:.0f} s from "
                                          f"{pred[1][0]} DOF/{pred[1][1]} in/{pred[1][2]} lines")
                res = run_case(c, run_solvers, args.timeout, args.threads) if run_solvers else {
                    "id": {}, "timed_out": None, "error": None}
                res["pre_skip"] = pre_skip
                for s, rec in res["id"].items():
                    rec["lnis_mb"] = 16 * c[2] * c[0] * c[1] * 2 * c[0] / 1e6
                    if s == "ml":
                        ml_measured[c] = rec
                results[c] = res
            res = results[c]
            svd = res.get("svd")
            for s in solvers:
                if s in res["id"]:
                    print(fmt_row(v, s, svd, res["id"][s]))
                elif s in res["pre_skip"]:
                    print(fmt_row(v, s, svd, None, res["pre_skip"][s]))
                elif res["timed_out"] == "svd":
                    print(fmt_row(v, s, svd, None, "failed: setup and SVD did not finish in "
                                                   f"{max(args.timeout, SETUP_S):g} s"))
                elif res["timed_out"] == s or (res["timed_out"] and s not in res["id"]):
                    print(fmt_row(v, s, svd, None, f"skipped (too slow): > {args.timeout:g} s"))
                else:
                    print(fmt_row(v, s, svd, None, f"failed: {res['error']}"))
            sys.stdout.flush()
    if args.profile:
        env = dict(os.environ)
        if args.threads:
            env.update({k: str(args.threads) for k in THREAD_VARS})
        sys.stdout.flush()
        subprocess.run([sys.executable, os.path.abspath(__file__), "--profile-worker",
                        "--solvers", ",".join(solvers)], env=env, check=False)
    print()
    print(f"# total bench wall time {time.perf_counter() - t_start:.0f} s; at end: {load_avg()}")


if __name__ == "__main__":
    main()
