"""Bench: physical-coordinates fit with reactions as known loads (ssid.reaction_fit) against truth.

usage: bench_reaction_fit.py {soft,base,chain,chaindef} ; prints M, K rel. errors and in-band roots
of the step-2 model (identify_mck as it is) and of the fit started from nothing and from step 2.
"""
import sys
import time

import numpy as np

sys.path.insert(0, "/work/qa_stand")
from ssid.identify import identify_mck  # noqa: E402
from ssid.noise import data_noise_weights  # noqa: E402
from ssid.reaction_fit import equation_error_mck, fit_mck_with_reactions  # noqa: E402
from ssid.result import model_frf_errors  # noqa: E402


def roots(M, C, K):
    n = M.shape[0]
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    lam = np.linalg.eigvals(A)
    lam = lam[lam.imag > 0]
    return np.sort(np.abs(lam)) / 2 / np.pi, lam


def report(tag, M, C, K, Mt, Ct, Kt, band, data, w):
    ft, _ = roots(Mt, Ct, Kt)
    try:
        fi, _ = roots(M, C, K)
    except np.linalg.LinAlgError:
        fi = np.array([np.nan])
    ib = ft[(ft >= band[0]) & (ft <= band[1])]
    df = [100 * (fi[np.argmin(np.abs(fi - f))] / f - 1) for f in ib]
    eM = np.linalg.norm(M - Mt) / np.linalg.norm(Mt)
    eK = np.linalg.norm(K - Kt) / np.linalg.norm(Kt)
    pd = np.linalg.eigvalsh(M).min() > 0
    cost, rel = model_frf_errors(data, M, C, K, w)
    print(f"{tag:22s} M {100*eM:8.3f}%  K {100*eK:8.3f}%  mass {M.sum():8.4f} (true {Mt.sum():.4f})  "
          f"M PD {pd}  FRF err {100*rel:.3f}%  in-band max|df| {np.nanmax(np.abs(df)):.4f}%", flush=True)
    print("    in-band df %:", " ".join(f"{x:+.3f}" for x in df), flush=True)
    import scipy.linalg as sla
    try:
        fu = np.sqrt(np.abs(sla.eigvalsh(K, M))) / 2 / np.pi
        fut = np.sqrt(np.abs(sla.eigvalsh(Kt, Mt))) / 2 / np.pi
        print("    undamped (K, M) df % all modes:", " ".join(f"{100*(a/b-1):+.2f}" for a, b in zip(fu, fut)),
              flush=True)
    except np.linalg.LinAlgError:
        print("    undamped: M not PD")


def case(name):
    if name in ("soft", "base"):
        from truthcmp import truth

        from ssid.io.frf_file import read_measured_frf
        setup, run = {"soft": ("/work/qa_stand/runs/soft.toml", "/work/qa_stand/runs/soft.h5"),
                      "base": ("/work/qa_stand/base/setup_sim.toml", "/work/qa_stand/base/run.h5")}[name]
        data = read_measured_frf(run)
        Mt, Ct, Kt, dt = truth(setup)
        idx = [dt.index(d) for d in data.outputs]
        return data, Mt[np.ix_(idx, idx)], Ct[np.ix_(idx, idx)], Kt[np.ix_(idx, idx)]
    from ssid.models import chain_model, frf_on_test_stand
    from ssid.noise import report_noise_frf
    stand = dict(stand_k_n_per_m=2e3, stand_c_n_s_per_m=400.0, ground_k_n_per_m=5e3) if name == "chain" else {}
    M, C, K, dofs = chain_model([1.0, 1.5, 0.8, 1.2, 1.0], [4e5, 3e5, 5e5, 2e5], np.zeros(5),
                                [8.0, 6.0, 10.0, 5.0], np.zeros(5))
    frf = frf_on_test_stand(M, C, K, dofs, ["2+Z", "4+Z"], ["1+Z", "5+Z"], np.geomspace(5.0, 400.0, 200), **stand)
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 1
    frf = report_noise_frf(frf, seed, mag_noise=0.002, phase_noise_deg=0.2, with_variance=True)
    return frf, M, C, K


if __name__ == "__main__":
    data, Mt, Ct, Kt = case(sys.argv[1])
    band = (data.freq_hz[0], data.freq_hz[-1])
    w = data_noise_weights(data)
    t = time.time()
    r = identify_mck(data)
    print(f"identify {time.time()-t:.1f}s; warnings on reactions:",
          [x[:60] for x in r.warnings if "reaction term" in x], flush=True)
    report("step2 (identify)", r.M, r.C, r.K, Mt, Ct, Kt, band, data, w)
    report("truth", Mt, Ct, Kt, Mt, Ct, Kt, band, data, w)
    t = time.time()
    M0, C0, K0 = equation_error_mck(data, w)
    print(f"eq-error {time.time()-t:.1f}s", flush=True)
    report("eq-error (no start)", M0, C0, K0, Mt, Ct, Kt, band, data, w)
    t = time.time()
    M1, C1, K1, info = fit_mck_with_reactions(data, w)
    print(f"eq+OE {time.time()-t:.1f}s", [(round(p['cost_start']), round(p['cost']), p['iterations'])
                                          for p in info['passes']], flush=True)
    report("eq-error + OE(EIV)", M1, C1, K1, Mt, Ct, Kt, band, data, w)
    M2, C2, K2, info = fit_mck_with_reactions(data, w, start=(r.M, r.C, r.K))
    report("from step2: eq+OE", M2, C2, K2, Mt, Ct, Kt, band, data, w)
