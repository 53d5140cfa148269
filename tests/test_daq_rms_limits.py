"""RMS limits under random excitation (``[limits] max_accel_rms_m_per_s2``, ``max_force_rms_n``,
``max_reaction_rms_n``): a continuous random run on the simulated lab (real transports, fixed
seeds) whose RMS exceeds its limit while its peaks stay below theirs is stopped like a peak
limit stops it, naming the RMS; one below completes; the setup refuses bad values and RMS
limits in a stepped-sine setup."""

from __future__ import annotations

import re

import h5py
import numpy as np
import pytest
from test_daq_helpers import all_safe, random_setup, run_on_sim, sine_setup

from daq.rms_limit import RMS_WINDOW_S, SlidingRms
from daq.safety import RANDOM_LIMIT_STOP, RunStopped, limit_usage, resume_remedy
from daq.setup import Limits, parse_setup
from ssid.errors import InputError

# One shaker at 0.5 Vpp, 40-200 Hz, sensor noise on: the accelerometers' 1 s RMS is
# 0.70-0.79 m/s^2 at peaks up to 2.74 m/s^2, the force's 1.53-1.58 N at peaks up to 5.4 N.
PEAK_LIMITS = "max_accel_m_per_s2 = 4.0\nmax_force_n = 8.0\n"


def _continuous(limits: str) -> str:
    return random_setup(kind="random", two=False, block=2048, settle=1, averages=4, noise=True) + \
        f"[limits]\n{PEAK_LIMITS}{limits}\n"


def _recording(monkeypatch) -> list[np.ndarray]:
    """Every piece the rig reads, kept for the test."""
    import daq.rig as rigmod

    pieces, acquire = [], rigmod.InstrumentRig.acquire

    def recorded(self, n):
        data = acquire(self, n)
        pieces.append(data)
        return data

    monkeypatch.setattr(rigmod.InstrumentRig, "acquire", recorded)
    return pieces


@pytest.mark.parametrize("limit, said", [
    ("max_accel_rms_m_per_s2 = 0.6",
     r"acceleration RMS 0\.[67]\d* m/s\^2 over the last 1 s on 'acc 1\+Z' above the limit 0\.6 m/s\^2"),
    ("max_force_rms_n = 1.2", r"force RMS 1\.[2-5]\d* N over the last 1 s on 'force 1\+Z' above the limit 1\.2 N"),
])
def test_an_rms_over_its_limit_stops_a_random_run_whose_peaks_stay_below(tmp_path, monkeypatch, limit, said):
    """The run stops as a peak limit stops it (drive off, state naming the RMS, a new run the
    remedy), within the first second, though no sample reached a peak limit."""
    pieces, worlds = _recording(monkeypatch), []
    setup = parse_setup(_continuous(limit), str(tmp_path / "s.toml"))
    with pytest.raises(RunStopped) as stop:
        run_on_sim(setup, tmp_path / "run.h5", on_start=worlds.append)
    assert re.fullmatch(f"{RANDOM_LIMIT_STOP}: {said}", str(stop.value)), str(stop.value)
    assert all_safe(worlds[0])
    with h5py.File(tmp_path / "run.h5") as f:
        state = f["acq"].attrs["state"]
    assert state == f"stopped: {stop.value}" and resume_remedy(state, sim=True) == "new_run"
    x = np.hstack(pieces)
    force, acc = [0], [1, 2, 3]
    assert np.max(np.abs(x[acc])) < 4.0 and np.max(np.abs(x[force])) < 8.0  # the peaks never tripped it
    assert x.shape[1] <= RMS_WINDOW_S * 4096  # tripped within the window: 0.75 / 0.6 over, 1/1.25^2 s


def test_a_random_run_below_its_rms_limits_completes_and_reports_their_use(tmp_path):
    events = []
    setup = parse_setup(_continuous("max_accel_rms_m_per_s2 = 1.0\nmax_force_rms_n = 2.0"), str(tmp_path / "s.toml"))
    summary, world = run_on_sim(setup, tmp_path / "run.h5", events=events.append)
    assert summary["state"] == "complete" and summary["n_avg"] == 4 and all_safe(world)
    use = [e["limit_use"] for e in events if e["event"] == "spectrum"]
    assert use and all(0.6 < u["acceleration RMS"] < 1.0 and 0.7 < u["force RMS"] < 1.0 for u in use), use
    assert all(u["acceleration"] < 1.0 for u in use)  # the peak use is reported beside it, as before


def test_sliding_rms_is_over_the_whole_window_from_the_start():
    """Before a window's worth the record before the drive counts as zero: a start never
    reads as more than it is, and a level k times the limit trips after 1/k^2 of the window."""
    w = SlidingRms(1, 100.0)
    assert w.add(np.full((1, 25), 2.0)) == pytest.approx([1.0])  # a quarter of the window at 2
    assert w.add(np.full((1, 100), 3.0)) == pytest.approx([3.0])  # the window slid past the start
    assert w.add(np.zeros((1, 50))) == pytest.approx([3.0 / np.sqrt(2)])


def test_limit_usage_reports_rms_beside_peak():
    lim = Limits(max_accel_m_per_s2=10.0, max_accel_rms_m_per_s2=2.0, max_force_rms_n=4.0)
    roles = {"force": [0], "response": [1, 2], "reaction": []}
    got = limit_usage(lim, np.array([3.0, 5.0, 2.0]), roles, 1.0, rms=np.array([1.0, 1.0, 1.5]))
    assert got == pytest.approx({"drive": 0.1, "acceleration": 0.5, "acceleration RMS": 0.75, "force RMS": 0.25})
    assert "acceleration RMS" not in limit_usage(lim, np.array([3.0, 5.0, 2.0]), roles, 1.0)  # stepped sine


@pytest.mark.parametrize("value", ["0", "0.0", "-1.5", "nan", "-inf", '"2"'])
@pytest.mark.parametrize("key", ["max_accel_rms_m_per_s2", "max_force_rms_n", "max_reaction_rms_n"])
def test_a_bad_rms_limit_is_refused(tmp_path, key, value):
    text = random_setup(kind="random") + f"[limits]\n{key} = {value}\n"
    with pytest.raises(InputError, match=rf"s\.toml: \[limits\] {key}: must be (in \(0, inf\]|a number)"):
        parse_setup(text, str(tmp_path / "s.toml"))


def test_rms_limits_are_read_and_default_to_none():
    got = parse_setup(random_setup(kind="random") + "[limits]\nmax_accel_rms_m_per_s2 = 2.5\n").limits
    assert (got.max_accel_rms_m_per_s2, got.max_force_rms_n, got.max_reaction_rms_n) == (2.5, np.inf, np.inf)


def test_an_rms_limit_in_a_stepped_sine_setup_is_refused_with_the_peak_that_says_the_same(tmp_path):
    text = sine_setup(limits="max_accel_rms_m_per_s2 = 2.0")
    with pytest.raises(InputError) as e:
        parse_setup(text, str(tmp_path / "s.toml"))
    assert str(e.value) == (f"{tmp_path / 's.toml'}: [limits] max_accel_rms_m_per_s2: RMS limits apply to random "
                            "excitation only; a stepped-sine line is limited by its peak: set max_accel_m_per_s2 "
                            "(a sine's peak is sqrt(2) times its RMS: 2.82843 m/s^2 for an RMS of 2 m/s^2)")
