"""Helpers shared by the TUI tests: a small simulated setup, waiting on the app, its log."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from tui.app import LabApp

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "setup_sim.toml"
SIZE = (80, 24)


def small_setup(tmp_path: Path, n_lines: int = 30) -> Path:
    """examples/setup_sim.toml with few lines and no refinement (a few seconds simulated)."""
    text = EXAMPLE.read_text(encoding="utf-8")
    out = []
    for line in text.splitlines():
        if line.startswith("n_lines ="):
            line = f"n_lines = {n_lines}"
        elif line.startswith("refine ="):
            line = "refine = 1"
        elif line.startswith("uff ="):
            continue
        out.append(line)
    path = tmp_path / "small.toml"
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


async def wait_for(pilot, cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            # The run's own log tells where a stalled run stopped (CI stalls went unexplained
            # twice): ask a run still going for its threads' stacks (ssidlab acquire prints
            # them on SIGUSR1) and give its output a moment to reach the log.
            acq = getattr(pilot.app, "acquisition", None)
            if acq is not None and acq.running:
                try:
                    os.kill(acq.proc.pid, signal.SIGUSR1)
                    await pilot.pause(2.0)
                except OSError:
                    pass
            try:
                tail = "\n".join(log_text(pilot.app).splitlines()[-120:])
            except Exception as exc:  # noqa: BLE001 -- the timeout is the failure; the log is extra
                tail = f"(no log: {exc})"
            raise AssertionError(f"timed out after {timeout} s waiting for {what}; the TUI log ends:\n{tail}")
        await pilot.pause(0.05)


async def abort_after_first_line(pilot, app: LabApp, timeout: float = 30) -> None:
    """F5, then F8 once the first line has been measured (deterministic: the file holds data),
    and wait for the run to stop."""
    await pilot.press("f5")
    await wait_for(pilot, lambda: "sub-lines" in log_text(app), timeout, "a first measured line")
    await pilot.press("f8")
    await wait_for(pilot, lambda: app.outcome is not None, 30, "the run to stop")


def log_text(app: LabApp) -> str:
    return "\n".join(strip.text for strip in app.query_one("#log").lines)
