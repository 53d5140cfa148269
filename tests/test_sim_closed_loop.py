"""Closed loop through every real transport: SCPI generator (pty) -> Modbus amplifier ->
shaker -> structure -> sensors -> CAN FD DAQ, measured by the drivers; and the standalone
``python -m sim_devices`` process."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys

import numpy as np
import pytest
from conftest import reap

from drivers.amplifier_sync import SyncShakerAmplifier
from drivers.daq import CanFdDaq, DaqChannel
from drivers.siggen import SignalGenerator
from sim_devices.effects import AddedMass, AttachedOscillator
from sim_devices.lab import SimLab, example_world

FS = 5120
F_HZ = 40.0  # 128 samples per period


def tone(x: np.ndarray, first_index: int, freq_hz: float) -> np.ndarray:
    """Complex amplitude at freq_hz of each row (Hann window: leakage of the decaying
    transients at the natural frequencies is negligible)."""
    idx = first_index + np.arange(x.shape[1])
    return (x * np.hanning(x.shape[1])) @ np.exp(-2j * np.pi * freq_hz * idx / FS)


@pytest.mark.parametrize("stand", [False, True], ids=["free", "stand+hidden-effects+2nd-shaker"])
def test_sine_ratio_equals_world_frf(stand):
    """The issue's closed-loop check (noise off, within 0.5 %).

    One shaker: acceleration / force equals the world's accelerance at the drive DOF. With
    a second (undriven, attached) shaker the structure also feels that shaker's passive
    force, measured by its own gauge, so the check becomes a = H1 F1 + H2 F2.
    """
    effects = [AddedMass("3+Z", 0.05), AttachedOscillator("6+Z", 0.3, 2e5, 5.0)] if stand else []
    shakers = ("1+Z", "8+Z") if stand else ("1+Z",)
    ns = len(shakers)
    world = example_world(shaker_dofs=shakers, stand=stand, effects=effects, noise=False)
    channels = [DaqChannel(f"force {d}", j, "force", 22.5) for j, d in enumerate(shakers)]
    channels += [DaqChannel("acc 1+Z", ns + 0), DaqChannel("acc 3+Z", ns + 2)]
    if stand:
        channels.append(DaqChannel("load 14+Z", ns + 14, "force", 22.5))
    with SimLab(world, generator_transport="pty") as lab, contextlib.ExitStack() as stack:
        gen = stack.enter_context(SignalGenerator(lab.generators[0].url, timeout_s=0.5, ramp_time_s=0.05, ramp_step_s=0.005))
        amp_ep = lab.endpoints()["amplifiers"][0]
        amp = stack.enter_context(SyncShakerAmplifier(amp_ep["host"], amp_ep["port"], poll_interval_s=0.05))
        daq = stack.enter_context(CanFdDaq(channel=lab.can_channel, timeout_s=0.5))
        gen.set_function(1, "SIN")
        gen.set_frequency(1, F_HZ)
        amp.set_gain(2.0)
        amp.enable()
        gen.output_on(1, vpp=1.0)
        daq.configure(channels, FS)
        n = 8 * FS
        daq.start(n)
        blk = daq.read(n, timeout_s=30.0)
        amp.check()
        tail = 2 * FS
        X = tone(blk.data[:, -tail:], blk.first_index + n - tail, F_HZ)
        F, A = X[:ns], X[ns : ns + 2]
        ref = world.frf([F_HZ], outputs=["1+Z", "3+Z"], inputs=list(shakers))
        predicted = ref.H[0] @ F
        np.testing.assert_allclose(A, predicted, rtol=5e-3)  # the issue asks for 0.5 %
        assert np.max(np.abs(A / predicted - 1)) < 1e-3  # it is in fact much closer
        if stand:
            assert abs(X[-1] / (ref.H_reaction[0] @ F)[0] - 1) < 5e-3
        else:
            assert abs(F[0]) > 0.1 and np.allclose(A / F[0], ref.H[0, :, 0], rtol=1e-3)
        g_ch = world.generators[0].channels[0]
        assert g_ch.output_on and world.amplifiers[0].enabled
    # Every exit path leaves excitation off.
    assert not g_ch.output_on and not world.amplifiers[0].enabled


def test_standalone_sim_lab_process():
    proc = subprocess.Popen([sys.executable, "-m", "sim_devices", "--speed", "0", "--no-noise", "--duration", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ep = json.loads(proc.stdout.readline())
        assert all(u.startswith("socket://127.0.0.1:") for u in ep["generators"])
        assert all(a["host"] == "127.0.0.1" for a in ep["amplifiers"]) and ep["daq"]["gateway"].startswith("127.0.0.1:")
        with SignalGenerator(ep["generators"][0], timeout_s=0.5, ramp_time_s=0.02, ramp_step_s=0.005) as gen, \
                SyncShakerAmplifier(ep["amplifiers"][0]["host"], ep["amplifiers"][0]["port"]) as amp, \
                CanFdDaq(interface="tcp", channel=ep["daq"]["gateway"], timeout_s=1.0) as daq:
            gen.set_function(1, "SIN")
            gen.set_frequency(1, F_HZ)
            amp.enable()
            gen.output_on(1, vpp=1.0)
            daq.configure([DaqChannel("force 1+Z", 0, "force", 22.5), DaqChannel("acc 1+Z", 2)], FS)
            daq.start(2 * FS)
            blk = daq.read(2 * FS, timeout_s=20.0)
            assert np.std(blk.data[0, -FS:]) > 0.1  # the shaker pushes
            assert amp.read_status().enabled
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        reap(proc)


def test_sim_lab_bad_options_exit_2():
    r = subprocess.run([sys.executable, "-m", "sim_devices", "--shakers", "99+Z", "--duration", "0"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "error" in r.stderr and "99+Z" in r.stderr
