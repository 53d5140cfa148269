"""Pause / resume between lines and the run's events (daq.control), on the simulated lab
through the real drivers: while paused every output is off and every amplifier disabled (read
from the simulated instruments), and the resumed run still measures the world's FRF."""

from __future__ import annotations

import signal
import threading

import h5py
import numpy as np
import pytest

from daq.control import RunControl, latching_interrupt_handler, raise_if_interrupted
from daq.safety import drive_headroom_vpp, limit_usage
from daq.setup import Limits, parse_setup
from daq.simlab import build_world
from ssid.io import read_frf

from test_daq_helpers import all_safe, frf_error, random_setup, run_on_sim, sine_setup


class PauseOnce:
    """Events sink: asks for a pause after ``after`` events of ``kind``; on ``paused`` records
    whether the instruments are safe (the world is read from the run's own thread, so nothing
    moves meanwhile), then asks for resume."""

    def __init__(self, control: RunControl, kind: str, after: int) -> None:
        self.control, self.kind, self.after = control, kind, after
        self.world = None
        self.events: list[dict] = []
        self.safe_while_paused: bool | None = None

    def __call__(self, ev: dict) -> None:
        self.events.append(ev)
        if ev["event"] == self.kind and sum(e["event"] == self.kind for e in self.events) == self.after:
            self.control.request_pause()
        elif ev["event"] == "paused":
            self.safe_while_paused = all_safe(self.world)
            assert self.control.paused
            # Resume from another thread, as a UI would.
            threading.Timer(0.2, self.control.request_resume).start()


def run_with_pause(tmp_path, text: str, kind: str, after: int):
    setup = parse_setup(text, str(tmp_path / "s.toml"))
    control = RunControl()
    sink = PauseOnce(control, kind, after)
    summary, world = run_on_sim(setup, tmp_path / "run.h5", on_start=lambda w: setattr(sink, "world", w),
                                control=control, events=sink)
    return setup, summary, world, sink


def test_stepped_sine_pause_goes_safe_and_resume_completes_the_run(tmp_path):
    setup, summary, world, sink = run_with_pause(tmp_path, sine_setup(two=True), "sub_line", 3)
    kinds = [e["event"] for e in sink.events]
    assert summary["state"] == "complete" and all_safe(world)
    assert kinds.count("paused") == 1 and kinds.count("resumed") == 1
    assert sink.safe_while_paused is True
    # Paused between lines: exactly three sub-lines before, none lost or doubled after.
    i = kinds.index("paused")
    assert kinds[:i].count("sub_line") == 3 and kinds.index("resumed") == i + 1
    frf = read_frf(tmp_path / "run.h5")
    assert kinds.count("line") == frf.n_freq and summary["n_aborted"] == 0
    assert np.max(frf_error(frf, build_world(setup))) < 5e-3  # same accuracy as without a pause
    # Events carry what the UI shows: identities first, level, distortion, limit use, amplifiers.
    assert kinds[0] == "instruments" and "gen0" in sink.events[0]["identities"]["generators"]
    sub = next(e for e in sink.events if e["event"] == "sub_line")
    assert sub["ok"] and sub["force_n"] > 0 and 0 <= sub["thd_max"] < 0.05
    assert 0 < sub["limit_use"]["drive"] < 1
    assert all(a["enabled"] and a["interlock_closed"] for a in sub["instruments"]["amplifiers"].values())
    line = next(e for e in sink.events if e["event"] == "line")
    assert np.shape(line["H_abs"]) == (frf.n_out, frf.n_in) == np.shape(line["coherence"])


def test_continuous_random_pause_restarts_an_unbroken_record(tmp_path):
    text = random_setup(kind="random", averages=12, block=1024, settle=2)
    setup, summary, world, sink = run_with_pause(tmp_path, text, "spectrum", 1)
    kinds = [e["event"] for e in sink.events]
    assert summary["state"] == "complete" and all_safe(world) and sink.safe_while_paused is True
    assert kinds.count("paused") == 1 and summary["n_avg"] == 12
    spectra = [e for e in sink.events if e["event"] == "spectrum"]
    assert spectra[-1]["n_avg"] == 12 and spectra[0]["n_avg"] < 12
    frf = read_frf(tmp_path / "run.h5")
    # Same criterion as without a pause (test_daq_random): Hann leakage limits continuous
    # random at the peaks, so the median error is what is checked.
    assert np.nanmedian(frf_error(frf, build_world(setup))) < 0.1


@pytest.mark.parametrize("peaks, used", [([1.0, 5.0, 2.0], {"drive": 0.5, "acceleration": 0.5, "force": 0.2}),
                                         ([0.0, 0.0, 0.0], {"drive": 0.5, "acceleration": 0.0, "force": 0.0})])
def test_limit_usage_is_peak_over_limit(peaks, used):
    lim = Limits(max_drive_vpp=2.0, max_force_n=5.0, max_accel_m_per_s2=10.0)
    roles = {"force": [0], "response": [1, 2], "reaction": []}
    got = limit_usage(lim, np.array(peaks), roles, drive_vpp=1.0)
    assert got == pytest.approx(used)  # no reaction channels, no infinite limit: left out


def test_drive_headroom_is_the_drive_that_reaches_the_first_limit():
    """Channels scale with the drive: measured at 1 Vpp, 2 N against 5 N and 4 m/s^2 against
    10 m/s^2 reach their limits at 2.5 Vpp both; 5 m/s^2 reaches its limit first, at 2 Vpp.
    Without a finite limit or a level there is no headroom to keep."""
    lim = Limits(max_drive_vpp=8.0, max_force_n=5.0, max_accel_m_per_s2=10.0)
    roles = {"force": [0], "response": [1, 2], "reaction": []}
    assert drive_headroom_vpp(lim, np.array([2.0, 4.0, 1.0]), roles, 1.0) == pytest.approx(2.5)
    assert drive_headroom_vpp(lim, np.array([2.0, 5.0, 1.0]), roles, 1.0) == pytest.approx(2.0)
    assert drive_headroom_vpp(Limits(), np.array([2.0, 5.0, 1.0]), roles, 1.0) == np.inf


class _InterruptInFinalizer:
    """Calls the run's SIGINT handler from its finalizer, the way Python runs a handler when
    the signal arrives while the garbage collector runs a finalizer: the KeyboardInterrupt it
    raises there is printed as "Exception ignored" and dropped (seen once in CI)."""

    def __init__(self, handler) -> None:
        self.handler = handler

    def __del__(self) -> None:
        self.handler(signal.SIGINT, None)


# The dropped exception is the point of these tests; pytest reports it as "unraisable".
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_an_interrupt_swallowed_by_a_finalizer_still_stops_the_run(tmp_path):
    """The Ctrl-C is raised inside a finalizer at a line boundary and lost there; the latch
    raises it again before the next acquisition, so the run stops as for any Ctrl-C: file
    ``interrupted`` with the lines done, generator outputs off, amplifiers disabled."""
    handler = latching_interrupt_handler(KeyboardInterrupt)
    setup = parse_setup(sine_setup(two=True), str(tmp_path / "s.toml"))
    worlds = []
    count = {"n": 0}

    def echo(msg):
        count["n"] += 1
        if count["n"] == 8:
            _InterruptInFinalizer(handler)  # dropped at once: __del__ runs, its exception is lost

    with pytest.raises(KeyboardInterrupt):
        run_on_sim(setup, tmp_path / "run.h5", on_start=worlds.append, echo=echo)
    with h5py.File(tmp_path / "run.h5") as f:
        assert f["acq"].attrs["state"] == "interrupted" and f["acq/n_done"][0] < 12
    assert all_safe(worlds[0])
    raise_if_interrupted()  # handled by the run: nothing left latched


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_the_latch_raises_the_interrupt_type_it_caught():
    class Terminated(KeyboardInterrupt):
        pass

    _InterruptInFinalizer(latching_interrupt_handler(Terminated))
    with pytest.raises(Terminated):
        raise_if_interrupted()
    raise_if_interrupted()  # raised once, then forgotten


def test_an_interrupt_swallowed_by_a_finalizer_prints_no_traceback():
    """Python printed the dropped interrupt as "Exception ignored in: ..." with a traceback on
    the command's stderr (QA: once in 100 interrupted resumes), though the latch raises it
    again. A real SIGINT, delivered inside a finalizer, in a process of its own."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = """
import os, signal
from daq.control import latching_interrupt_handler, raise_if_interrupted
signal.signal(signal.SIGINT, latching_interrupt_handler(KeyboardInterrupt))

class Dies:
    def __del__(self):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):  # the handler runs between these bytecodes, inside the finalizer
            pass

Dies()
try:
    raise_if_interrupted()
except KeyboardInterrupt:
    print("raised again")
"""
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(root)})
    assert proc.stdout == "raised again\n" and proc.stderr == "", proc.stderr


def test_a_run_latches_ctrl_c_while_it_runs_and_restores_the_handler(tmp_path):
    """Called with Python's default SIGINT handler (the demo, a script), the run puts the
    latching one in place for its duration and restores the default after."""
    setup = parse_setup(sine_setup(), str(tmp_path / "s.toml"))
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    seen = []
    run_on_sim(setup, tmp_path / "run.h5", echo=lambda m: seen.append(signal.getsignal(signal.SIGINT)))
    assert seen and all(h is not signal.default_int_handler for h in seen)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
