"""Simulated test time of our stepped sine against a fixed-cycle baseline and the physical minimum.

    python bench/sweep_time.py [--setup examples/setup_sim.toml] [--accuracy 1e-3] [--quick]

The setup's world (the payload simulator on its stand, two shakers, 21 channels, noise off)
is driven directly (``daq.simlab.WorldRig``: the same world and run logic as
``ssidlab acquire --sim``, without the transports, so only simulated time counts).

Rows (one sweep over the same frequency lines, both shakers):

* ``ours``: ``daq.stepped_sine`` - adaptive line spacing, settling by the measured transient
  decay, level control;
* ``fixed 20/20``: every line 20 cycles of settling then 20 cycles of dwell (a common
  default), at our lines and drive levels;
* ``fixed N/8 (equal accuracy)``: the smallest fixed settle cycle count N (dwell 8 cycles,
  as ours) whose worst line error is no larger than ours;
* ``physical minimum``: for each of our lines, restarting from the world state our line
  started from, the earliest settling time after which the window estimate stays within
  the line's accuracy (the requested accuracy, or our error on that line if larger) -
  the true transient decays with the true damping - plus the same dwell.

Line error: ``|y - y_true| / |y_true|`` of the responses per unit active force (and of the
reactions, the larger of the two), ``y_true`` from the world's continuous-time state-space
model. Prints a plain-text table.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from daq.estimate import SineFit  # noqa: E402
from daq.run import run_test  # noqa: E402
from daq.setup import load_setup  # noqa: E402
from daq.simlab import WorldRig, build_world  # noqa: E402
from daq.steady_state import WINDOW_STEPS  # noqa: E402


class SnapRig(WorldRig):
    """WorldRig that remembers the world state at the start of every line."""

    def __init__(self, setup, world) -> None:
        super().__init__(setup, world)
        self.snaps: list[tuple] = []
        self._last = None

    def sine(self, shaker: int, freq_hz: float, vpp: float) -> None:
        if self._last != (shaker, freq_hz):
            self.snaps.append((shaker, freq_hz, snapshot(self.world), self.clock))
            self._last = (shaker, freq_hz)
        super().sine(shaker, freq_hz, vpp)

    def drive_off(self, shaker: int) -> None:
        self._last = None
        super().drive_off(shaker)


def snapshot(w) -> dict:
    return {"eta": w._eta.copy(), "u": w._u_prev.copy(), "idx": w.sample_index,
            "aa": None if w._antialias is None else w._antialias._hist.copy(),  # the DAQ filter's memory
            "gens": [copy.deepcopy(g.channels) for g in w.generators],
            "amps": [(a.enabled, a.gain_v_per_v) for a in w.amplifiers]}


def restore(w, s: dict) -> None:
    w._eta, w._u_prev, w.sample_index = s["eta"].copy(), s["u"].copy(), s["idx"]
    if s["aa"] is not None:
        w._antialias._hist = s["aa"].copy()
    for g, ch in zip(w.generators, s["gens"]):
        g.channels = copy.deepcopy(ch)
    for a, (en, gain) in zip(w.amplifiers, s["amps"]):
        a.enabled, a.gain_v_per_v = en, gain


class Truth:
    """Steady-state sensor amplitudes per unit drive from the world's state-space model."""

    def __init__(self, setup, world) -> None:
        self.w, self.rows = world, [c.input for c in setup.channels]
        roles = setup.roles()
        self.resp, self.react, self.force = roles["response"], roles["reaction"], roles["force"]

    def y(self, p: int, f: float) -> np.ndarray:
        w = self.w
        G = w._Cout[: len(w.sensors)] @ np.linalg.solve(2j * np.pi * f * np.eye(w._A.shape[0]) - w._A, w._B[:, p])
        g = G[self.rows]
        return g / g[self.force[p]]

    def error(self, X: np.ndarray, p: int, f: float) -> float:
        yt = self.y(p, f)
        ym = X / X[self.force[p]]
        errs = []
        for idx in (self.resp, self.react):
            if idx:
                errs.append(np.linalg.norm(ym[idx] - yt[idx]) / np.linalg.norm(yt[idx]))
        return float(max(errs))


def window_sizes(fs: float, f: float, spec) -> tuple[int, int]:
    n_w = max(spec.min_cycles * fs / f, spec.min_dwell_s * fs, 16.0)
    n_c = int(np.ceil(n_w / WINDOW_STEPS))
    return n_c * WINDOW_STEPS, n_c


def run_ours(setup, world):
    rig = SnapRig(setup, world)
    out = Path(f"/tmp/sweep_time_{id(rig)}.h5")
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    s = run_test(dataclasses.replace(setup, uff_file=None), out=str(out), rig_factory=lambda st: rig,
                 echo=lambda m: None)
    import h5py

    with h5py.File(out) as f:
        rec = {k: f["acq/records"][k][()] for k in f["acq/records"]}
    out.unlink(missing_ok=True)
    return rig, rec, s, time.perf_counter() - t0


def fixed_run(setup, lines, settle_cycles: float, dwell_cycles: float, truth) -> tuple[float, np.ndarray]:
    """Every line: settle, then dwell, fixed cycle counts; same lines, order and drives."""
    world = build_world(setup)
    rig = WorldRig(setup, world)
    rig.prepare()
    fs, total, errs, prev = rig.fs_hz, 0, [], None
    for p, f, vpp in lines:
        if prev is not None and prev != p:
            rig.drive_off(prev)
        prev = p
        rig.sine(p, f, vpp)
        n_s, n_d = int(np.ceil(settle_cycles * fs / f)), int(np.ceil(dwell_cycles * fs / f))
        if n_s:
            rig.acquire(n_s)
        data = rig.acquire(n_d)
        X = SineFit(f, fs, n_d).fit(data, start=n_s).X
        total += n_s + n_d
        errs.append(truth.error(X, p, f))
    return total / fs, np.array(errs)


def physical_minimum(setup, rig: SnapRig, rec, truth, accuracy: float, our_err: np.ndarray) -> tuple[float, int]:
    """Sum over lines of (earliest settle meeting the line's accuracy, staying there) + dwell."""
    world, fs, spec = rig.world, rig.fs_hz, setup.sine
    replay = WorldRig(setup, world)
    total, missed = 0.0, 0
    for i, (p, f, snap, _) in enumerate(list(rig.snaps)):
        vpp = float(rec["drive_vpp"][i])
        n_w, n_c = window_sizes(fs, f, spec)
        eps = max(accuracy, our_err[i])
        restore(world, snap)
        replay.sine(p, f, vpp)
        step = max(1, n_c // 4)
        horizon = int((rec["settle_s"][i] + rec["dwell_s"][i]) * fs * 1.5) + n_w
        data = replay.acquire(horizon)
        fit = SineFit(f, fs, n_w)
        starts = np.arange(0, horizon - n_w + 1, step)
        errs = np.array([truth.error(fit.fit(data[:, s:s + n_w], start=s).X, p, f) for s in starts])
        bad = np.flatnonzero(errs > eps)
        if bad.size and bad[-1] == starts.size - 1:
            missed += 1
            t_min = horizon - n_w
        else:
            t_min = 0 if not bad.size else starts[bad[-1] + 1]
        total += (t_min + n_w) / fs
    return total, missed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setup", default=str(Path(__file__).resolve().parents[1] / "examples" / "setup_sim.toml"))
    ap.add_argument("--accuracy", type=float, default=None, help="override [stepped_sine] accuracy")
    ap.add_argument("--quick", action="store_true", help="one shaker, 20-400 Hz")
    args = ap.parse_args()
    setup = load_setup(args.setup)
    setup.sim["noise"] = False
    if args.quick:
        setup = dataclasses.replace(setup, sine=dataclasses.replace(setup.sine, f_max_hz=400.0, n_lines=20))
    if args.accuracy:
        setup = dataclasses.replace(setup, sine=dataclasses.replace(setup.sine, accuracy=args.accuracy))
    acc = setup.sine.accuracy
    world = build_world(setup)
    truth = Truth(setup, world)
    rig, rec, summary, wall = run_ours(setup, world)
    lines = [(int(p), float(f), float(v)) for p, f, v in zip(rec["pattern"], rec["freq_hz"], rec["drive_vpp"])]
    ours_err = np.array([truth.error(X, p, f) for (p, f, _), X in zip(lines, rec["X"])])
    t_ours = float(np.sum(rec["settle_s"] + rec["dwell_s"]))
    t_min, missed = physical_minimum(setup, rig, rec, truth, acc, ours_err)
    t_fix, e_fix = fixed_run(setup, lines, 20, 20, Truth(setup, build_world(setup)))
    # Smallest fixed settle (cycles, dwell 8) whose worst error is no larger than ours.
    target = float(ours_err.max())
    lo, hi = 0.0, 800.0
    best = None
    for _ in range(9):
        mid = 0.5 * (lo + hi)
        t, e = fixed_run(setup, lines, mid, setup.sine.min_cycles, Truth(setup, build_world(setup)))
        if e.max() <= target:
            hi, best = mid, (mid, t, e)
        else:
            lo = mid
    if best is None:
        t, e = fixed_run(setup, lines, hi, setup.sine.min_cycles, Truth(setup, build_world(setup)))
        best = (hi, t, e)
    s = setup.sine
    print(f"setup: {args.setup}; {len(setup.shakers)} shakers, {len(setup.channels)} channels, "
          f"{s.f_min_hz:g}-{s.f_max_hz:g} Hz, requested accuracy {acc:g}, noise off")
    print(f"lines: {len(set(k for k in rec['grid_index']))} frequencies x {len(setup.shakers)} shakers = "
          f"{len(lines)} sub-lines (grid {summary['n_grid']}); our run took {wall:.1f} s wall")
    print()
    print(f"{'method':<32} {'test time s':>11} {'vs min':>7} {'max err':>9} {'p95 err':>9}")
    equal = "equal accuracy" if best[2].max() <= target else "the cap, less accurate"
    rows = [("ours", t_ours, ours_err), ("fixed 20/20 cycles", t_fix, e_fix),
            (f"fixed {best[0]:.0f}/8 cycles ({equal})", best[1], best[2])]
    for name, t, e in rows:
        print(f"{name:<32} {t:>11.1f} {t / t_min:>7.2f} {e.max():>9.2e} {np.percentile(e, 95):>9.2e}")
    print(f"{'physical minimum':<32} {t_min:>11.1f} {1.0:>7.2f} {'(per line: max(acc, ours))':>20}")
    if missed:
        print(f"note: {missed} lines did not reach their accuracy within 1.5x our time (counted at that time)")


if __name__ == "__main__":
    main()
