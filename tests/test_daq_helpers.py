"""Shared pieces of the tests/test_daq_*.py files (no tests here): small setups for the simulated lab."""

from __future__ import annotations

import argparse

import numpy as np

from ssid.errors import InputError

BASE = """
[test]
name = "daq test"
[output]
file = "run.h5"
[daq]
sample_rate_hz = 4096
[[generators]]
name = "gen0"
url = "socket://127.0.0.1:1"
max_vpp = 4.0
ramp_time_s = 0.01
[[amplifiers]]
name = "amp0"
port = 1
gain_v_per_v = 2.0
[[shakers]]
dof = "1+Z"
generator = "gen0"
channel = 1
amplifier = "amp0"
force_channel = "force 1+Z"
[[channels]]
name = "force 1+Z"
input = 0
dof = "1+Z"
quantity = "force"
sensitivity_mv_per_unit = 22.5
range_volt = 5.0
[[channels]]
name = "acc 1+Z"
input = 1
dof = "1+Z"
quantity = "acceleration"
sensitivity_mv_per_unit = 10.0
[[channels]]
name = "acc 3+Z"
input = 2
dof = "3+Z"
quantity = "acceleration"
sensitivity_mv_per_unit = 10.0
[[channels]]
name = "acc 7+Z"
input = 3
dof = "7+Z"
quantity = "acceleration"
sensitivity_mv_per_unit = 10.0
"""

SECOND_SHAKER = """
[[amplifiers]]
name = "amp1"
port = 2
gain_v_per_v = 2.0
[[shakers]]
dof = "7+Z"
generator = "gen0"
channel = 2
amplifier = "amp1"
force_channel = "force 7+Z"
[[channels]]
name = "force 7+Z"
input = 4
dof = "7+Z"
quantity = "force"
sensitivity_mv_per_unit = 22.5
range_volt = 5.0
"""

REACTION = """
[[channels]]
name = "load 14+Z"
input = 5
dof = "14+Z"
quantity = "reaction"
sensitivity_mv_per_unit = 22.5
[[channels]]
name = "acc 14+Z"
input = 6
dof = "14+Z"
quantity = "acceleration"
sensitivity_mv_per_unit = 10.0
"""


def sine_setup(f_min=110.0, f_max=200.0, n_lines=4, refine=3, noise=False, two=False, reaction=False,
               extra="", limits="", accuracy=2e-3, sim_extra="") -> str:
    """A small stepped-sine setup on the 14-DOF example world (modes at 119, 140, 154, 179 Hz)."""
    return (BASE + (SECOND_SHAKER if two else "") + (REACTION if reaction else "") + f"""
[excitation]
type = "stepped_sine"
[stepped_sine]
f_min_hz = {f_min}
f_max_hz = {f_max}
n_lines = {n_lines}
refine = {refine}
force_n = 1.0
accuracy = {accuracy}
max_change = 0.3
{extra}
[limits]
{limits}
[sim]
structure = "example"
noise = {str(noise).lower()}
{sim_extra}
[sim.stand]
stand_c_n_s_per_m = 1500.0
""")


def random_setup(kind="periodic", noise=False, averages=6, two=True, block=2048, settle=6,
                 noise_v=2e-6) -> str:
    return (BASE + (SECOND_SHAKER if two else "") + f"""
[excitation]
type = "random"
[random]
kind = "{kind}"
f_min_hz = 40
f_max_hz = 200
block_size = {block}
averages = {averages}
settle_blocks = {settle}
drive_vpp = 0.5
[sim]
structure = "example"
noise = {str(noise).lower()}
sensor_noise_volt_rms = {noise_v}
""")


def ctrl_c_at_line(n: int):
    """A run's echo that raises KeyboardInterrupt (Ctrl-C) at its ``n``-th progress line."""
    seen = 0

    def echo(msg: str) -> None:
        nonlocal seen
        seen += 1
        if seen == n:
            raise KeyboardInterrupt

    return echo


def pointed_at(text: str, inst) -> str:
    """``text`` (a setup built on ``BASE``, one shaker or two) with the addresses of the
    instruments of ``inst``, the setup :func:`daq.simlab.start_sim_lab` pointed at its lab: run
    without the sim switch, the drivers reach the simulated instruments as they would real
    ones."""
    g, d = inst.generators[0], inst.daq
    swaps = [('url = "socket://127.0.0.1:1"', f'url = "{g.url}"'),
             ("[daq]\n", f'[daq]\ninterface = "{d.interface}"\nchannel = "{d.channel}"\n')]
    for j, a in enumerate(inst.amplifiers):
        swaps.append((f'name = "amp{j}"\nport = {j + 1}\n',
                      f'name = "amp{j}"\nhost = "{a.host}"\nport = {a.port}\ndevice_id = {a.device_id}\n'))
    for old, new in swaps:
        assert old in text, old
        text = text.replace(old, new)
    return text


def cli(argv: list[str]) -> tuple[int, str]:
    """Run ``ssidlab acquire`` as ``ssidlab.cli.main`` would: status and the error line."""
    from ssidlab.cli import _Parser, _UsageError
    from ssidlab.cli_acquire import add_acquire_subcommand

    root = _Parser(prog="ssidlab")
    sub = root.add_subparsers(dest="command", required=True)
    add_acquire_subcommand(sub)
    try:
        args = root.parse_args(["acquire", *argv])
        return args.run(args), ""
    except _UsageError as exc:
        return 2, exc.message
    except InputError as exc:
        return 2, str(exc)


def frf_error(frf, world) -> np.ndarray:
    """Relative error of each line and input: |H - H_true| / |H_true| over the outputs."""
    ref = world.frf(frf.freq_hz, outputs=frf.outputs, inputs=frf.inputs)
    H = np.where(frf.valid_mask(), frf.H, np.nan)
    return np.linalg.norm(H - ref.H, axis=1) / np.linalg.norm(ref.H, axis=1)


def run_on_sim(setup, out, on_start=None, **kw):
    """Run ``setup`` against a simulated lab started here, so the test can read the
    instruments' state; ``on_start(world)`` is called before the run. Returns (summary, world)."""
    from daq.run import run_test
    from daq.simlab import start_sim_lab

    handle, inst = start_sim_lab(setup)
    try:
        if on_start is not None:
            on_start(handle.world)
        return run_test(inst, out=str(out), echo=kw.pop("echo", lambda m: None), **kw), handle.world
    finally:
        handle.stop()


def all_safe(world) -> bool:
    """Every generator output off and every amplifier disabled (read from the simulators)."""
    gens = all(not c.output_on for g in world.generators for c in g.channels)
    return gens and not any(a.enabled for a in world.amplifiers)


def argparse_ns(**kw) -> argparse.Namespace:
    return argparse.Namespace(**kw)


def killed_at_write(path, nth_write: int) -> list[str]:
    """The command prefix (strace fault injection) that kills (-9) the command after it at its
    ``nth_write`` write (pwrite64) to the file ``path``."""
    return ["strace", "-f", "-o", "/dev/null", "-P", str(path), "-e", "trace=pwrite64", "-e",
            f"inject=pwrite64:signal=KILL:when={nth_write}"]
