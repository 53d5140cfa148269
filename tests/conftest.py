"""Shared fixtures: a small 3-DOF spring-mass chain and FRF data synthesised from it."""

from __future__ import annotations

import itertools
import os
import platform
import signal
import threading


def _pin_openblas_kernels() -> None:
    """Run OpenBLAS's Haswell (AVX2) kernels whatever x86 CPU the tests land on.

    The wheels' OpenBLAS picks its kernels for the CPU at load time, and AVX-512 and AVX2
    kernels sum in different orders: the same run then differs in the last digits, which a
    screen snapshot of an ill-conditioned number (an out-of-band mode's M, K frequency) shows.
    Pinning makes the tests give the same digits on every CI machine; it must happen before
    numpy is imported, hence here at the top of the first conftest.
    """
    if platform.machine() not in ("x86_64", "AMD64"):
        return
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            has_avx2 = " avx2" in f.read()
    except OSError:
        return
    if has_avx2:
        os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")


def _one_blas_thread() -> None:
    """One OpenBLAS thread per test process (and the commands it runs, which inherit it).

    The suite runs two workers on two cores; each worker's OpenBLAS would start a thread per
    core, four busy threads on two cores, and the workers' matrix solves then wait on each
    other's threads. One thread each also gives the same digits whether the tests run one or
    two at a time. Like the kernel pin, it must be set before numpy is imported.
    """
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


_pin_openblas_kernels()
_one_blas_thread()

import numpy as np  # noqa: E402  (after the kernel pin above)
import pytest

from ssid.frf import FRFData, accelerance_from_model
from ssid.io import Model

DOFS = ["1+Z", "2+Z", "3+Z"]


def chain_model() -> Model:
    """Grounded 3-mass chain: masses 1, 2, 1.5 kg; springs 1e4 N/m; light viscous damping."""
    m = np.diag([1.0, 2.0, 1.5])
    k = 1e4 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    c = 2e-4 * k + 0.5 * m
    return Model(M=m, K=k, C=c, dofs=list(DOFS))


def uniform_chain(n: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, C, K) of a fixed-free spring-mass chain, 1 kg and 1e6 N/m per link, Rayleigh
    damping ``1e-5 K + 2 M`` (for n = 4: modes at 55, 159, 244 and 299 Hz)."""
    M = np.eye(n)
    K = 1e6 * (2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    K[-1, -1] = 1e6
    return M, 1e-5 * K + 2.0 * M, K


def chain_frf(inputs: list[str] | None = None, n_freq: int = 64) -> FRFData:
    """Noise-free accelerances of :func:`chain_model`, outputs at all three DOFs."""
    model = chain_model()
    freq = np.linspace(2.0, 60.0, n_freq)
    return accelerance_from_model(
        model.M, model.C, model.K, model.dofs, freq, DOFS, inputs or ["1+Z", "3+Z"]
    )


def full_frf() -> FRFData:
    """FRF data with every optional item filled, including a blanked (NaN) value."""
    frf = chain_frf()
    rng = np.random.default_rng(0)
    shape = frf.H.shape
    frf.coherence = rng.uniform(0.5, 1.0, shape)
    frf.valid = np.ones(shape, dtype=bool)
    frf.valid[5, 1, 0] = False
    frf.H = frf.H.copy()
    frf.H[5, 1, 0] = np.nan
    frf.H_var = rng.uniform(1e-6, 1e-4, shape)
    frf.reactions = ["1+Z"]
    frf.H_reaction = rng.normal(size=(frf.n_freq, 1, frf.n_in)) + 1j * rng.normal(
        size=(frf.n_freq, 1, frf.n_in)
    )
    frf.n_avg = 20
    frf.H_reaction_var = rng.uniform(1e-6, 1e-4, frf.H_reaction.shape)
    frf.attrs = {"operator": "test bench", "temperature_c": 21.5}
    return frf


@pytest.fixture
def model() -> Model:
    return chain_model()


@pytest.fixture
def frf() -> FRFData:
    return chain_frf()


@pytest.fixture
def frf_full() -> FRFData:
    return full_frf()


def _payload_record(n_sensors: int, f_max_hz: float) -> tuple[FRFData, np.ndarray]:
    """The payload's ``n_sensors`` EfI Z sensors (Eq. 6.1) for its first ``n_sensors`` target
    modes, inputs at the interface (always measured), 2 % modal damping, 1 Hz to
    ``f_max_hz`` in 512 lines, as the replication bench builds its records. Returns
    ``(frf, f_hz)``, ``f_hz`` the undamped natural frequencies inside the record."""
    import scipy.linalg as sla

    from ssid.models.payload import (
        INTERFACE_DOFS,
        Z_DOFS,
        modal_damping,
        payload_simulator,
        target_modes,
    )
    from ssid.placement import effective_independence

    p = payload_simulator()
    lam, phi = sla.eigh(p.K, p.M)
    f_true = np.sqrt(lam) / (2 * np.pi)
    tm = target_modes(p, n_sensors)
    iz = p.index(Z_DOFS)
    chosen = effective_independence(phi[iz][:, tm], n_sensors, Z_DOFS, required=INTERFACE_DOFS)
    sensors = [d for d in Z_DOFS if d in chosen]
    frf = accelerance_from_model(p.M, modal_damping(p.M, p.K, 0.02), p.K, p.dofs,
                                 np.linspace(1.0, f_max_hz, 512), sensors, list(INTERFACE_DOFS))
    return frf, f_true[f_true <= f_max_hz]


@pytest.fixture(scope="module")
def payload_10dof_300hz():
    """The payload's 10 EfI sensors, 1-300 Hz in 512 lines (the report's first spectrum;
    df = 0.585 Hz; :func:`_payload_record`). Seven modes lie in the record; the 1.29 Hz
    suspension mode's half-power band (2 zeta f = 0.05 Hz) falls between two lines."""
    return _payload_record(10, 300.0)


@pytest.fixture(scope="module")
def payload_12dof_1158hz():
    """The payload's 12 EfI sensors, 1-1158 Hz in 512 lines (the replication's spectrum
    equivalent to the report's 1-650 Hz at 12 DOFs; df = 2.26 Hz; :func:`_payload_record`).
    Fifteen modes lie in the record; the 1.29 Hz suspension mode lies 0.29 Hz above the
    first line, 11 half-widths away."""
    return _payload_record(12, 1158.0)


@pytest.fixture(scope="session")
def log_sweep_record():
    """The payload's 16 Z DOFs (Guyan), 2 % modal damping, shakers at 11+Z and 16+Z, as
    the simulated lab's stepped-sine example measures them: 152 lines 20-1500 Hz on a log
    grid (2.9 % apart, 0.6 Hz at the bottom, 42 Hz at the top). Returns (frf, f_hz), f_hz the
    undamped natural frequencies inside the record."""
    import scipy.linalg as sla

    from ssid.models.payload import Z_DOFS, modal_damping, payload_simulator
    from ssid.tam import guyan_reduce

    p = payload_simulator()
    red = guyan_reduce(p.M, p.K, p.index(Z_DOFS))
    f = 20.0 * np.geomspace(1.0, 75.0, 152)
    frf = accelerance_from_model(red.M, modal_damping(red.M, red.K, 0.02), red.K, list(Z_DOFS), f,
                                 list(Z_DOFS), ["11+Z", "16+Z"])
    fn = np.sqrt(sla.eigvalsh(red.K, red.M)) / (2 * np.pi)
    return frf, fn[(fn >= f[0]) & (fn <= f[-1])]


def driven_world(**kw):
    """The simulated lab's example world, noise-free, generator 1 channel 1 driving a 37 Hz
    sine at 1 Vpp through an enabled amplifier (the DAQ driver tests' structure)."""
    from sim_devices.lab import example_world

    w = example_world(noise=False, **kw)
    ch = w.generators[0].channels[0]
    ch.function, ch.freq_hz, ch.vpp, ch.output_on = "SIN", 37.0, 1.0, True
    w.amplifiers[0].request_enable()
    return w


def two_shaker_world():
    """The example structure, noise-free, with shakers at 1+Z (generator channel 1) and 5+Z
    (channel 2): the world of the signal generator driver tests."""
    from sim_devices.components import ShakerSpec
    from sim_devices.world import World
    from ssid.models import example_system

    M, C, K, dofs = example_system()
    return World(M, C, K, dofs, shakers=[ShakerSpec("1+Z"), ShakerSpec("5+Z", channel=2)], noise=False)


_daq_channels = itertools.count()


@pytest.fixture
def rig():
    """(world, simulated DAQ, DAQ driver) on a fresh python-can virtual channel, the world
    :func:`driven_world`; the driver closed and the simulator stopped afterwards."""
    from drivers.daq import CanFdDaq
    from drivers.errors import InstrumentError
    from sim_devices.daq_sim import SimDaq

    name = f"test-daq-{next(_daq_channels)}"
    world = driven_world()
    sim = SimDaq(world, name).start()
    daq = CanFdDaq(channel=name, timeout_s=0.3, stream_timeout_s=0.5)
    yield world, sim, daq
    try:
        daq.close()
    except InstrumentError:
        pass
    sim.stop()


@pytest.fixture
def ssidlab(capsys):
    """Run ``ssidlab ...`` in this process: (exit status, stdout, stderr). (Some modules
    define their own, with more set up around the command.)"""
    from ssidlab import cli

    def run(*argv):
        status = cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return status, out, err

    return run


def reap(proc) -> None:
    """Kill ``proc`` (a subprocess.Popen with text pipes) if a failed test left it running, and
    close its pipes."""
    if proc.poll() is None:
        proc.kill()
        proc.wait(timeout=5)
    proc.stdout.close()
    proc.stderr.close()


def read_uff_with_warnings(path) -> tuple[FRFData, list[str]]:
    """A UFF file read as an FRF (``ssid.exchange.read_uff_frf``) and the warnings it gave."""
    import warnings

    from ssid.exchange import read_uff_frf

    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        frf = read_uff_frf(path)
    return frf, [str(w.message) for w in record]


def one_error_line(err: str, command: str) -> str:
    """The one line ``ssidlab <command>: error: ...`` that a refusal writes to stderr."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ssidlab {command}: error: "), err
    return lines[0]


@pytest.fixture
def ctrl_c_after():
    """``schedule(delay_s)``: a Ctrl-C (SIGINT to this process) ``delay_s`` from now, taken by
    Python's own handler, as in a user's script that drives the instruments; the main thread
    only. Pending ones are cancelled at the test's end."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers belong to the main thread")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    timers: list[threading.Timer] = []

    def schedule(delay_s: float) -> None:
        timers.append(threading.Timer(delay_s, os.kill, (os.getpid(), signal.SIGINT)))
        timers[-1].start()

    yield schedule
    for t in timers:
        t.cancel()
