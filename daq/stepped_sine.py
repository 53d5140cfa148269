"""The stepped-sine run: schedule -> sub-lines on the rig -> FRF lines in the run file.

Each sub-line (one shaker, one frequency) is measured by :class:`daq.sine_line.SineLine`
and written to the run file's records and committed before the next one starts. When
every shaker has measured a line, its FRFs follow from the multi-input solve
``H = X_A X_F^-1`` (:func:`daq.estimate.multi_input_frf`, all gauges' forces, so the
passive force of an undriven shaker is accounted for) and are written to the contract
view with their variance and a coherence-like quality ``|H|^2 / (|H|^2 + var H)``, where
``var H`` holds the noise of the fit and the transient left at the end of the settling; the
AC/IEPE channels' coupling high-pass is divided out (:mod:`daq.coupling`).
Values whose quality is below ``[quality] min_coherence`` are blanked (``valid`` False).

Resume: the records of the interrupted run are fed back to the schedule in order (each
must be the line the schedule asks for), which rebuilds its decisions and the level
controller's history exactly; measuring then continues with the first line not recorded.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from drivers.errors import SensorOverload
from ssid.errors import InputError
from ssid.frf import FRFData

from .control import RunControl, RunEvents, frf_line_event, hold_if_paused, raise_if_interrupted
from .coupling import coupling_response, undo_coupling
from .estimate import frf_quality, multi_input_frf
from .rig import Rig
from .safety import (
    MAX_OVER_RANGE_IN_ROW,
    LineAborted,
    LineOverRange,
    drive_headroom_vpp,
    limit_usage,
    over_range_in_row,
)
from .schedule import frequency_grid, sweep_plan
from .setup import TestSetup
from .sine_line import MIN_DRIVE_VPP, NOTCH_MARGIN, LineResult, SineLine, initial_drive
from .steady_state import record_noise_floor
from .storage import STATUS_ABORTED, STATUS_OK, RunFile

__all__ = ["SteppedSineRun", "sine_grid"]


#: The words of a kept sub-line's reason when its level was held below its target.
HELD = "held below a limit"
#: Marks in a kept line's ``reason`` that a limit aborted its first attempt.
MEASURED_AGAIN = "measured again: its first attempt"
#: Length of each read while an aborted line's ringing decays (s).
RING_DOWN_READ_S = 0.05


def sine_grid(setup: TestSetup) -> np.ndarray:
    s = setup.sine
    return frequency_grid(s.f_min_hz, s.f_max_hz, s.n_lines, s.spacing, s.refine)


def _variance_with_transient(row: dict) -> np.ndarray:
    """Per-channel variance of a sub-line: the fit's noise plus the transient left at the end
    of settling, which counts as uncertainty like noise (``X_transient``, shaped like the
    modes still ringing, :meth:`daq.sine_line.SineLine.transient_per_channel`). Records
    without it (files from before it was kept) take the relative transient times each
    amplitude."""
    X, var = np.abs(np.asarray(row["X"])), np.asarray(row["X_var"], float)
    tr = np.asarray(row.get("X_transient", np.full(X.shape, np.nan)), float)
    return var + np.where(np.isfinite(tr), tr, float(row["transient"]) * X) ** 2


class SteppedSineRun:
    """One stepped-sine run (new or resumed) on ``rig``, stored in ``runfile``."""

    def __init__(self, setup: TestSetup, rig: Rig, runfile: RunFile, echo: Callable[[str], None] = print,
                 control: RunControl | None = None, events: RunEvents | None = None) -> None:
        self.setup, self.rig, self.rf, self.echo = setup, rig, runfile, echo
        self.control, self.events = control, events or RunEvents()
        self.spec = setup.sine
        self.roles = setup.roles()
        self.grid = sine_grid(setup)
        control = None if self.spec.control == "force" else setup.channel_index(self.spec.control)
        self.ctl_channel = control
        self.drive_limits_vpp = [setup.drive_limit_vpp(p) for p in range(len(setup.shakers))]
        self.ranges = setup.channel_ranges()
        self.line = SineLine(rig, self.spec, setup.limits, self.roles, self.drive_limits_vpp, control,
                             keep_raw=setup.raw_time, ranges=self.ranges)
        self.target = self.spec.force_n if control is None else self.spec.control_target
        self.n_pat = len(setup.shakers)
        self.rows: dict[tuple[int, int], dict] = {}
        self.history: dict[int, list[tuple[float, float, float]]] = {p: [] for p in range(self.n_pat)}
        # Per shaker, the drive at which the last kept line's channels would reach their limits
        # or DAQ ranges.
        self.headroom_vpp: dict[int, float] = {p: math.inf for p in range(self.n_pat)}
        self.replay = list(self._recorded_rows())
        self.replayed = 0
        self.n_done = runfile.n_done
        self.active: int | None = None
        self.test_time_s = float(sum(r["settle_s"] + r["dwell_s"] for r in self.replay))
        self.over_range_in_row = 0  # live sub-lines aborted by a DAQ over-range, one after another

    def _recorded_rows(self):
        rec = self.rf.records()
        n = len(rec.get("grid_index", []))
        for i in range(n):
            row = {k: v[i] for k, v in rec.items()}
            # the file holds the reason as bytes; a live row as str
            row["reason"] = bytes(row.get("reason", b"")).decode("utf-8", "replace")
            yield row

    # ------------------------------------------------------------------ per sub-line
    def _y(self, X: np.ndarray, p: int) -> np.ndarray:
        return X[self.roles["response"]] / X[self.roles["force"][p]]

    def _control_level(self, X: np.ndarray, p: int) -> float:
        ch = self.ctl_channel if self.ctl_channel is not None else self.roles["force"][p]
        return float(abs(X[ch]))

    def _level_off(self, X: np.ndarray, p: int) -> float | None:
        """A line's control level over the target when outside the level control's
        tolerance, else None (the one test both the record's reason and the summary use)."""
        ratio = self._control_level(X, p) / self.target
        return ratio if abs(ratio - 1) > self.spec.tolerance else None

    def _level_note(self, res: LineResult) -> str:
        """What a kept line's control level was when the level control could not bring it
        within the tolerance (held below a limit, corrections or settling time used up);
        '' when it did."""
        ratio = self._level_off(res.est.X, res.pattern)
        if ratio is None:
            return ""
        if res.limited:
            return f"level {ratio:.2f} of the target, {HELD}: {res.limited}"
        return f"level {ratio:.2f} of the target (tolerance {self.spec.tolerance:g})"

    def measure(self, p: int, k: int) -> np.ndarray | None:
        """Callback of the schedule: the response vector per unit force, or None (aborted)."""
        if self.replayed < len(self.replay):
            row = self.replay[self.replayed]
            if int(row["pattern"]) != p or int(row["grid_index"]) != k:
                raise InputError(
                    f"{self.rf.path}: record {self.replayed} is shaker {int(row['pattern'])} line "
                    f"{int(row['grid_index'])}, but the schedule asks for shaker {p} line {k}: "
                    "the file does not belong to this setup and schedule")
            self.replayed += 1
            return self._accept(p, k, row, live=False)
        return self._measure_live(p, k)

    def _measure_live(self, p: int, k: int) -> np.ndarray | None:
        f = float(self.grid[k])
        if hold_if_paused(self.control, self.rig, self.rf, self.echo, self.events,
                          f"before shaker {p} {f:.3f} Hz"):
            self.active = None  # the safe state switched every output off
        self.rig.line_check()
        if self.active is not None and self.active != p:
            self.rig.drive_off(self.active)
        self.active = p
        vpp = initial_drive(self.history[p], f, self.target, self.spec, self.drive_limits_vpp[p])
        # The first drive is extrapolated from the control level alone; kept below what takes
        # the last line's channels to their limits, with room for the response to change by
        # max_change. Past a point where the target needs more than a limit, the extrapolation
        # had every following line start at the drive limit: 8 Vpp put 80-88 N on a 50 N force
        # limit, line after line, until the DAQ clipped and the run stopped.
        vpp = min(vpp, max(self.headroom_vpp[p] / (1 + self.spec.max_change), MIN_DRIVE_VPP))
        nch = len(self.rig.names)
        t0 = self.rig.clock
        over_range = None  # the DAQ fault that aborted the line, if one did
        first_try = ""  # the line's first attempt, when a limit aborted it
        t_retry = t0
        while True:
            try:
                res = self.line.measure(p, f, vpp, self.target, settled_steps=bool(first_try))
                row = self._row(k, res, STATUS_OK, "; ".join(filter(None, [self._level_note(res), first_try])))
                if first_try:  # the first attempt's time was test time too
                    row["settle_s"] += (t_retry - t0) / self.rig.fs_hz
            except LineAborted as exc:
                self.rig.drive_off(p)  # the drive goes to zero before anything else
                if not first_try and not isinstance(exc, LineOverRange) and math.isfinite(exc.headroom_vpp):
                    # A limit exceeded by the line's first drive (extrapolated from the line
                    # before, with a resonance between them) or by a correction's transient.
                    # Aborted at once, such lines were lost: the 14-DOF example under a
                    # 1.2 m/s^2 limit lost its lines at two resonances, 117.6 and 143.5 Hz.
                    # The line is measured again from below the drive the exceeding record
                    # says reaches the limit, every level settled before the next: that
                    # record may have been read while the resonance built up (at 117.6 Hz,
                    # 1.38 m/s^2 in the first window at 0.125 Vpp, where the settled response
                    # is 1.79), hence a further compression^2 of room. The level control
                    # then holds the line below the limit if its target needs more.
                    first_try = f"{MEASURED_AGAIN}, at {exc.drive_vpp:.3g} Vpp, was aborted: {exc}"
                    vpp = max(MIN_DRIVE_VPP, min(NOTCH_MARGIN * exc.headroom_vpp, exc.drive_vpp)
                              / self.spec.compression ** 2)
                    self.echo(f"  line {k} shaker {p} {f:.2f} Hz: {exc} at {exc.drive_vpp:.3g} Vpp; "
                              f"measured again from {vpp:.3g} Vpp")
                    self._let_ring_down()
                    t_retry = self.rig.clock
                    continue
                if isinstance(exc, LineOverRange):
                    over_range = exc.fault
                dt = (self.rig.clock - t0) / self.rig.fs_hz
                reason = str(exc) + (f" ({first_try})" if first_try else "")
                row = {"grid_index": k, "pattern": p, "freq_hz": f, "drive_vpp": exc.drive_vpp,
                       "status": STATUS_ABORTED, "settle_s": dt, "dwell_s": 0.0, "transient": 1.0, "decay": 0.0,
                       "wall_time": time.time(), "X": np.full(nch, np.nan + 0j), "X_var": np.zeros(nch),
                       "thd": np.zeros(nch), "X_transient": np.full(nch, np.nan), "reason": reason}
                res = None
                self.echo(f"  line {k} shaker {p} {f:.2f} Hz aborted at {exc.drive_vpp:.3g} Vpp: {reason}")
            break
        self.rf.append_record(row)
        if res is not None and res.raw is not None:
            self.rf.append_raw(res.raw)
        y = self._accept(p, k, row, live=True)
        self.n_done += 1
        self.rf.commit(self.n_done)
        # Printed only once committed: a line the engineer saw is a line a resume keeps.
        if res is not None:
            self.echo(f"  shaker {p} {row['freq_hz']:9.3f} Hz  drive {row['drive_vpp']:.3f} Vpp  "
                      f"|F| {abs(row['X'][self.roles['force'][p]]):.3g} N  settle {row['settle_s']:.3f} s  "
                      f"dwell {row['dwell_s']:.3f} s  [{self.n_done} sub-lines, {self.test_time_s:.1f} s test time]"
                      + (f"  {row['reason']}" if row["reason"] else ""))
        if self.events:
            self._sub_line_event(row, res)
        self.over_range_in_row = self.over_range_in_row + 1 if over_range else 0
        if self.over_range_in_row >= MAX_OVER_RANGE_IN_ROW:
            raise over_range_in_row(over_range, self.over_range_in_row, "sub-lines")
        return y

    def _let_ring_down(self) -> None:
        """With the drive off after an aborted attempt, read until every limited channel is
        below half its limit, for at most ``max_settle_s``: a resonance rings on for several
        time constants: measured again at once, the 14-DOF example's 117.6 Hz line exceeded
        its 1.2 m/s^2 limit again, in its first window, at a sixth of the first attempt's drive."""
        fs = self.rig.fs_hz
        n = max(1, int(RING_DOWN_READ_S * fs))
        t_end = self.rig.clock + self.spec.max_settle_s * fs
        while self.rig.clock < t_end:
            raise_if_interrupted()
            try:
                peaks = np.max(np.abs(self.rig.acquire(n)), axis=1)
            except SensorOverload:
                continue  # still ringing beyond a range; the clock counts these scans too
            used = limit_usage(self.setup.limits, peaks, self.roles, 0.0)
            if max((v for key, v in used.items() if key != "drive"), default=0.0) < 0.5:
                return

    def _sub_line_event(self, row: dict, res: LineResult | None) -> None:
        """The sub-line as the engineer watches it: level, distortion, limit use, amplifiers."""
        fields = {"shaker": int(row["pattern"]), "grid_index": int(row["grid_index"]),
                  "freq_hz": float(row["freq_hz"]), "drive_vpp": float(row["drive_vpp"]),
                  "ok": res is not None, "reason": row["reason"], "n_sub_lines": self.n_done,
                  "test_time_s": self.test_time_s, "instruments": self.rig.status()}
        if res is not None:
            X = res.est.X
            F = X[self.roles["force"][res.pattern]]
            # The response per unit force of this shaker alone: what the line's FRF column
            # will be, up to the other shakers' passive forces (solved once all have run).
            fields["Y_abs"] = np.abs(X[self.roles["response"]] / F) if abs(F) > 0 else None
            fields.update(force_n=float(abs(F)),
                          thd_max=float(np.max(res.est.thd[self.roles["response"]])) if self.roles["response"] else 0.0,
                          limit_use=limit_usage(self.setup.limits, res.est.peak, self.roles, res.drive_vpp))
        self.events.emit("sub_line", **fields)

    def _row(self, k: int, res: LineResult, status: int, reason: str) -> dict:
        return {"grid_index": k, "pattern": res.pattern, "freq_hz": res.freq_hz, "drive_vpp": res.drive_vpp,
                "status": status, "settle_s": res.settle_s, "dwell_s": res.dwell_s,
                "transient": res.transient, "decay": res.decay, "wall_time": time.time(),
                "X": res.est.X, "X_var": res.est.var, "thd": res.est.thd,
                "X_transient": res.x_transient if res.x_transient is not None else np.full(len(res.est.X), np.nan),
                "reason": reason}

    def _accept(self, p: int, k: int, row: dict, live: bool) -> np.ndarray | None:
        """Book a sub-line (live or replayed): history, FRF line when complete, progress."""
        self.rows[(p, k)] = row
        if live:
            self.test_time_s += float(row["settle_s"] + row["dwell_s"])
        if int(row["status"]) != STATUS_OK:
            return None
        X = np.asarray(row["X"])
        self.history[p].append((float(row["freq_hz"]), float(row["drive_vpp"]), self._control_level(X, p)))
        self.headroom_vpp[p] = drive_headroom_vpp(self.setup.limits, np.abs(X), self.roles, float(row["drive_vpp"]),
                                                  self.ranges)
        self.line.decay_prev = float(row["decay"])
        if not live:
            F = X[self.roles["force"][p]]
            for g, idx in enumerate((self.roles["response"], self.roles["reaction"])):
                if idx and abs(F) > 0:
                    self.line.group_ref[g] = max(self.line.group_ref[g], float(np.linalg.norm(X[idx] / F)))
        if all((q, k) in self.rows for q in range(self.n_pat)):
            self._write_line(k)
        return self._y(X, p)

    # ------------------------------------------------------------------ FRF lines
    def line_frf(self, k: int) -> dict:
        """H, variance, quality and validity of grid line ``k`` from its sub-lines."""
        rows = [self.rows[(p, k)] for p in range(self.n_pat)]
        r, a, fi = self.roles["reaction"], self.roles["response"], self.roles["force"]
        n_out, n_r = len(a), len(r)
        if any(int(x["status"]) != STATUS_OK for x in rows):
            return {"H": np.full((n_out, self.n_pat), np.nan + 0j), "var": np.zeros((n_out, self.n_pat)),
                    "coh": np.zeros((n_out, self.n_pat)), "valid": np.zeros((n_out, self.n_pat), bool),
                    "Hr": np.zeros((n_r, self.n_pat), complex), "Hr_var": np.zeros((n_r, self.n_pat))}
        X = np.stack([np.asarray(x["X"]) for x in rows], axis=1)  # (n_ch, n_pat)
        V = np.stack([_variance_with_transient(x) for x in rows], axis=1)
        H, var = multi_input_frf(X[a], X[fi], V[a], V[fi])
        Hr, Hr_var = (multi_input_frf(X[r], X[fi], V[r], V[fi]) if n_r
                      else (np.zeros((0, self.n_pat), complex), np.zeros((0, self.n_pat))))
        # The records hold the channels as read; the AC/IEPE high-pass is divided out here.
        c = coupling_response(self.setup, self.grid[k])[0]
        H, var = undo_coupling(H, var, c[a], c[fi])
        Hr, Hr_var = undo_coupling(Hr, Hr_var, c[r], c[fi])
        coh = frf_quality(H, var)
        valid = (coh >= self.setup.min_coherence) & np.isfinite(H)
        return {"H": H, "var": var, "coh": coh, "valid": valid, "Hr": Hr, "Hr_var": Hr_var}

    def _write_line(self, k: int) -> None:
        d = self.line_frf(k)
        react = bool(self.roles["reaction"])
        self.rf.write_line(k, d["H"], d["var"], d["coh"], d["valid"], d["Hr"] if react else None,
                           d["Hr_var"] if react else None)
        if self.events:
            self.events.emit("line", grid_index=int(k), **frf_line_event(self.grid[k], d["H"], d["coh"], d["valid"]))

    # ------------------------------------------------------------------ the run
    def run(self) -> dict:
        s = self.spec
        if self.replay:
            self.echo(f"resuming: {len(self.replay)} sub-lines on file, replaying the schedule")
        # The noise floor (all drives off) sets the noise of every estimate: the residual of
        # a fit would also hold the transient still decaying while settling.
        self.line.noise_var, took_s = record_noise_floor(self.rig, self.setup.channels, self.rf)
        self.test_time_s += took_s
        sweep_plan(self.measure, self.n_pat, len(self.grid), s.refine, s.max_change)
        if self.replayed < len(self.replay):
            raise InputError(f"{self.rf.path}: {len(self.replay) - self.replayed} records beyond the end of "
                             "the schedule: the file does not belong to this setup")
        if self.active is not None:
            self.rig.drive_off(self.active)
            self.active = None
        return self.summary()

    def frf(self) -> FRFData:
        """The compact FRF of every completed line (blanked values: NaN, valid False)."""
        lines = sorted({k for (_, k) in self.rows if all((q, k) in self.rows for q in range(self.n_pat))})
        parts = [self.line_frf(k) for k in lines]
        setup = self.setup
        frf = FRFData(
            freq_hz=self.grid[lines], H=np.array([np.where(d["valid"], d["H"], np.nan) for d in parts]),
            outputs=setup.outputs, inputs=setup.inputs,
            coherence=np.array([d["coh"] for d in parts]), valid=np.array([d["valid"] for d in parts]),
            H_var=np.array([np.where(np.isfinite(d["var"]), d["var"], 0.0) for d in parts]))
        if setup.reactions:
            frf.H_reaction = np.array([np.nan_to_num(d["Hr"]) for d in parts])
            frf.H_reaction_var = np.array([np.where(np.isfinite(d["Hr_var"]), d["Hr_var"], 0.0)
                                           for d in parts])
            frf.reactions = setup.reactions
        return frf

    def summary(self) -> dict:
        rows = list(self.rows.values())
        ok = [r for r in rows if int(r["status"]) == STATUS_OK]
        # From the level itself, not from the reason: a line measured again after a limit
        # says so in its reason whatever its level.
        off = [r for r in ok if self._level_off(np.asarray(r["X"]), int(r["pattern"])) is not None]
        frf = self.frf()
        return {
            "excitation": "stepped_sine", "n_grid": int(len(self.grid)), "n_lines": int(frf.n_freq),
            "n_sub_lines": len(rows), "n_aborted": len(rows) - len(ok),
            # held below a target a limit would not let them reach (notching: expected)
            "n_held": sum(1 for r in off if HELD in r["reason"]),
            # kept with the control level outside the tolerance for want of corrections or time
            "n_level_off": sum(1 for r in off if HELD not in r["reason"]),
            # kept after a limit aborted their first attempt (retried below it)
            "n_measured_again": sum(1 for r in ok if MEASURED_AGAIN in r["reason"]),
            "n_values_blanked": int(np.count_nonzero(~frf.valid_mask())), "n_values": int(frf.H.size),
            "test_time_s": self.test_time_s,
            "settle_time_s": float(sum(r["settle_s"] for r in rows)),
            "dwell_time_s": float(sum(r["dwell_s"] for r in rows)),
            "max_thd": float(max((np.nanmax(r["thd"]) for r in ok), default=0.0)),
        }

