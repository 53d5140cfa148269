"""What the TUI does besides drawing: start ``ssidlab acquire`` as a subprocess, stop it with
SIGINT, turn its progress lines into a fraction, read the results.

No science or device logic here: the acquisition is ``python -m ssidlab acquire`` (``daq``),
the identification ``ssid.identify.identify_mck`` on ``ssid.io.read_frf``. ``daq.run_test``
has no stop hook a thread could use, so the run lives in its own process and an abort is the
same SIGINT as Ctrl-C, which ``daq`` handles safely (instruments to the safe state, the run
file kept readable and resumable).
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Acquisition", "ModeRow", "ProgressParser", "RunOutcome", "identify_file", "run_file_state"]

#: Exit statuses of ``ssidlab acquire`` (docs/acquisition.md).
EXIT_TEXT = {0: "complete", 2: "bad input", 3: "stopped safely by a fault", 130: "interrupted (safe)"}


class Acquisition:
    """One ``ssidlab acquire SETUP [--sim] --out FILE`` subprocess, stdout and stderr merged."""

    def __init__(self, setup_path: str | Path, out: str | Path, *, sim: bool = True) -> None:
        self.setup_path = str(setup_path)
        self.out = str(out)
        self.sim = sim
        self.proc: subprocess.Popen[str] | None = None
        self.abort_requested = False

    @property
    def argv(self) -> list[str]:
        argv = [sys.executable, "-m", "ssidlab", "acquire", self.setup_path, "--out", self.out]
        if self.sim:
            argv.append("--sim")
        return argv

    def start(self) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        # Own session: a Ctrl-C typed into the terminal reaches the TUI only; the TUI decides.
        self.proc = subprocess.Popen(self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, text=True, bufsize=1, env=env,
                                     start_new_session=True)

    def lines(self) -> Iterator[str]:
        """The subprocess's output lines until it closes its output."""
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            yield line.rstrip("\n")

    def wait(self, timeout: float | None = None) -> int:
        assert self.proc is not None
        return self.proc.wait(timeout)

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def abort(self) -> bool:
        """Ask the run to stop as Ctrl-C would (SIGINT). False if it is not running."""
        if not self.running:
            return False
        self.abort_requested = True
        assert self.proc is not None
        try:
            self.proc.send_signal(signal.SIGINT)
        except ProcessLookupError:
            return False
        return True

    def shutdown(self, grace_s: float = 15.0) -> None:
        """Stop and reap the subprocess: SIGINT (safe stop), then SIGKILL after ``grace_s``."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.abort()
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


_SINE = re.compile(r"^\s*shaker\s+(\d+)\s+([0-9.eE+-]+)\s+Hz\b")
_RANDOM = re.compile(r"^\s*average\s+(\d+)/(\d+)\b")


class ProgressParser:
    """Fraction done (0..1) from the acquisition's progress lines, or None if a line says nothing.

    Stepped sine: each shaker sweeps the band in turn (log spacing over frequency); random:
    ``average k/N``. The sweep's refinement makes the stepped-sine fraction an estimate.
    """

    def __init__(self, excitation: str, f_min_hz: float, f_max_hz: float, n_shakers: int) -> None:
        self.excitation = excitation
        self.f_min, self.f_max = float(f_min_hz), float(f_max_hz)
        self.n_shakers = max(1, int(n_shakers))
        self.best = 0.0

    @classmethod
    def for_setup(cls, setup) -> ProgressParser:
        if setup.excitation == "stepped_sine":
            f0, f1 = setup.sine.f_min_hz, setup.sine.f_max_hz
        else:
            f0, f1 = setup.random.f_min_hz, setup.random.f_max_hz
        return cls(setup.excitation, f0, f1, len(setup.shakers))

    def feed(self, line: str) -> float | None:
        m = _RANDOM.match(line)
        if m:
            frac = int(m.group(1)) / max(1, int(m.group(2)))
        else:
            m = _SINE.match(line)
            if not m:
                return None
            p, f = int(m.group(1)), float(m.group(2))
            if not (self.f_max > self.f_min > 0 and f > 0):
                return None
            part = math.log(f / self.f_min) / math.log(self.f_max / self.f_min)
            frac = (p + min(max(part, 0.0), 1.0)) / self.n_shakers
        # Late refinement lines go back down in frequency: never move the bar backwards.
        self.best = max(self.best, min(frac, 1.0))
        return self.best


@dataclass
class RunOutcome:
    returncode: int
    aborted: bool
    file: str
    state: str | None  # the run file's /acq state, when readable

    @property
    def complete(self) -> bool:
        return self.returncode == 0

    def summary(self) -> str:
        what = EXIT_TEXT.get(self.returncode, f"failed (exit status {self.returncode})")
        if self.aborted and self.returncode != 0:
            what = f"aborted: {what}"
        tail = f"; run file state {self.state!r}" if self.state else ""
        return f"run {what}{tail}"


def run_file_state(path: str | Path) -> str | None:
    """The ``/acq`` ``state`` attribute of a run file (read-only), or None."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            return str(f["acq"].attrs["state"])
    except Exception:  # noqa: BLE001 -- no file, not HDF5, no /acq: nothing to show
        return None


@dataclass
class ModeRow:
    mode: int
    freq_hz: float
    damping_ratio: float
    mpc: float
    in_band: bool = True  # within the band of lines used for the fit


def identify_file(path: str | Path) -> tuple[list[ModeRow], str]:
    """Identify M, C, K from a finished FRF file; the modes and a one-line description."""
    from ssid.identify import identify_mck
    from ssid.io import read_frf

    frf = read_frf(path)
    res = identify_mck(frf)
    lo, hi = res.band_hz
    rows = [ModeRow(i + 1, float(f), float(z), float(m), bool(lo <= f <= hi))
            for i, (f, z, m) in enumerate(zip(res.natural_freq_hz, res.damping_ratio, res.mpc, strict=False))]
    desc = (f"{Path(path).name}: {frf.n_freq} lines, {frf.n_out} outputs x {frf.n_in} inputs; "
            f"{len(rows)} modes ({res.solver}, {res.band_hz[0]:.4g}-{res.band_hz[1]:.4g} Hz)")
    return rows, desc
