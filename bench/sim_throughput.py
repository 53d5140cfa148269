"""Throughput of the simulated measurement chain: world + CAN FD encode/decode + DAQ driver.

The bundled 14-DOF example with two shakers driven by random noise, 16 channels
(2 force gauges, 14 accelerometers) at 5120 S/s, sensor noise on. The DAQ simulator
advances the world as fast as it can (no pacing) and sends 64-byte CAN FD frames; the
driver (``drivers.daq.CanFdDaq``) receives, checks and decodes them and returns aligned
blocks of 0.25 s. The ratio is simulated seconds per wall-clock second, from START to the
last block (the issue asks for >= 10x on 2 cores).

Transports:

* ``virtual`` (default): simulator and driver in this process on a python-can virtual bus;
  one process, so the GIL makes it use about one core.
* ``tcp``: the simulated lab as a separate process (``python -m sim_devices``), the
  driver reaching its CAN bus through the CAN-over-TCP gateway: two processes, two cores.

Run:  python bench/sim_throughput.py [--seconds 20] [--repeat 3] [--transport virtual|tcp|both]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.daq import CanFdDaq, DaqChannel
from drivers.daq_protocol import bus_load
from sim_devices.daq_sim import SimDaq
from sim_devices.lab import example_world

FS = 5120
BLOCK = FS // 4


def channels(names: list[str]) -> list[DaqChannel]:
    return [DaqChannel(n, k, "force" if n.startswith("force") else "acceleration",
                       22.5 if n.startswith("force") else 10.0, 10.0, "IEPE") for k, n in enumerate(names)]


def acquire(daq: CanFdDaq, seconds: float) -> float:
    """Acquire ``seconds`` of 16 channels; wall time from START to the last sample."""
    n_total = int(seconds * FS)
    t0 = time.perf_counter()
    daq.start(n_total)
    got = 0
    while got < n_total:
        blk = daq.read(min(BLOCK, n_total - got), timeout_s=120.0)
        got += blk.data.shape[1]
    return time.perf_counter() - t0


def run_virtual(seconds: float) -> tuple[float, dict]:
    world = example_world(noise=True, seed=1)
    for g in world.generators:
        for ch in g.channels:
            ch.function, ch.vpp, ch.output_on = "NOIS", 1.0, True
    for amp in world.amplifiers:
        amp.gain_v_per_v = 2.0
        amp.request_enable()
    name = "bench-throughput"
    with SimDaq(world, name), CanFdDaq(channel=name, timeout_s=1.0, stream_timeout_s=5.0) as daq:
        daq.configure(channels([s.name for s in world.sensors]), FS)
        wall = acquire(daq, seconds)
        return wall, daq.stats


def run_tcp(seconds: float) -> tuple[float, dict]:
    proc = subprocess.Popen([sys.executable, "-m", "sim_devices", "--speed", "0", "--seed", "1"],
                            stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[1])
    try:
        ep = json.loads(proc.stdout.readline())
        # Drive both shakers with noise through the real generator and amplifier drivers.
        from drivers.amplifier_sync import SyncShakerAmplifier
        from drivers.siggen import SignalGenerator

        with SignalGenerator(ep["generators"][0], ramp_time_s=0.02, ramp_step_s=0.005) as gen:
            amps = [SyncShakerAmplifier(a["host"], a["port"]) for a in ep["amplifiers"]]
            try:
                for ch in (1, 2):
                    gen.set_function(ch, "NOIS")
                for amp in amps:
                    amp.set_gain(2.0)
                    amp.enable()
                for ch in (1, 2):
                    gen.output_on(ch, vpp=1.0)
                with CanFdDaq(interface="tcp", channel=ep["daq"]["gateway"], timeout_s=1.0, stream_timeout_s=5.0) as daq:
                    daq.configure(channels(ep["daq"]["inputs"]), FS)
                    wall = acquire(daq, seconds)
                    return wall, daq.stats
            finally:
                for amp in amps:
                    amp.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        proc.stdout.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per run (default 20)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per transport; the best is reported (default 3)")
    ap.add_argument("--transport", choices=("virtual", "tcp", "both"), default="virtual")
    args = ap.parse_args()
    fps, load = bus_load(16, FS, 1_000_000, 5_000_000)
    print(f"16 channels x {FS} S/s, 24-bit samples, 19 per 64-byte CAN FD frame: {fps:.0f} frames/s "
          f"({100 * load:.0f} % of a 1 Mbit/s / 5 Mbit/s bus)")
    print(f"{'transport':>9} {'sim_s':>6} {'wall_s':>7} {'frames/s':>9} {'lost':>4}  ratio (sim/wall)")
    transports = ("virtual", "tcp") if args.transport == "both" else (args.transport,)
    for tr in transports:
        best = None
        for _ in range(args.repeat):
            wall, stats = (run_virtual if tr == "virtual" else run_tcp)(args.seconds)
            lost = sum(s["lost"] for s in stats.values())
            frames = sum(s["frames"] for s in stats.values())
            if best is None or wall < best[0]:
                best = (wall, frames, lost)
        wall, frames, lost = best
        print(f"{tr:>9} {args.seconds:6.1f} {wall:7.3f} {frames / wall:9.0f} {lost:4d}  {args.seconds / wall:.1f}x real time")


if __name__ == "__main__":
    main()
