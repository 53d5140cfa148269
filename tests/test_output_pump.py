"""A run never waits for the reader of its output (ssidlab.output_pump).

The pipes here are shrunk to one page (F_SETPIPE_SZ, Linux) so that a few lines of output
fill them: a write then blocks exactly as it does when a busy UI, a terminal stopped with
Ctrl-S or a pager stops reading a run's 64 KB pipe.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import pytest

from ssid.io import read_frf
from ssidlab.output_pump import OutputPump
from test_daq_helpers import sine_setup

ROOT = Path(__file__).resolve().parents[1]
PAGE = 4096

pytestmark = pytest.mark.skipif(not hasattr(fcntl, "F_SETPIPE_SZ"), reason="needs Linux pipes")


def small_pipe() -> tuple[int, int]:
    r, w = os.pipe()
    fcntl.fcntl(w, fcntl.F_SETPIPE_SZ, PAGE)
    return r, w


def read_all(fd: int) -> bytes:
    chunks = []
    while chunk := os.read(fd, 65536):
        chunks.append(chunk)
    return b"".join(chunks)


def test_a_run_whose_output_is_not_read_goes_on_to_the_end(tmp_path):
    """Before the pump, the run's thread blocked in its first print past the pipe's capacity,
    mid-line with the drive on (and its limit checks with it) until the reader read again."""
    (tmp_path / "s.toml").write_text(sine_setup(n_lines=12))
    r, w = small_pipe()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ssidlab", "acquire", str(tmp_path / "s.toml"), "--sim", "--events",
             "--out", str(tmp_path / "run.h5")],
            stdout=w, stderr=w, stdin=subprocess.DEVNULL, cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)))
        os.close(w)
        try:
            rc = proc.wait(120)  # nobody reads meanwhile
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        unread = read_all(r)
    finally:
        os.close(r)
    assert rc == 0, unread.decode(errors="replace")
    with h5py.File(tmp_path / "run.h5") as f:
        assert f["acq"].attrs["state"] == "complete"
    n_lines = read_frf(tmp_path / "run.h5").freq_hz.size
    # The run printed more than the pipe holds (an event per measured line), and ended
    # without anyone reading it: what the pipe holds is its first events only.
    assert 0 < unread.count(b'"event":"line"') < n_lines


@contextlib.contextmanager
def std_streams_on_a_small_pipe():
    """sys.stdout and sys.stderr on one small pipe, set inside the test (pytest's capture sets
    its own streams between a fixture's setup and the test's call)."""
    r, w = small_pipe()
    out = open(w, "w", encoding="utf-8", closefd=False)  # noqa: SIM115 -- closed below
    saved = sys.stdout, sys.stderr
    sys.stdout = sys.stderr = out
    try:
        yield r, w
    finally:
        sys.stdout, sys.stderr = saved
        out.close()
        for fd in (w, r):
            try:
                os.close(fd)
            except OSError:  # the test closed it
                pass


def fill_the_pipe(pump: OutputPump, lines: list[str]) -> int:
    """Print the first of ``lines`` until the pump's writer has filled the pipe; return how many.

    Nobody reads, so the writer writes no more, and the pump's limit then counts from a fixed
    point. Without the wait, a writer thread scheduled late (a loaded 2-core machine) filled
    the pipe only after the dropping had begun, and freed room for a later line (seen: lines
    0-405, then 1895 on).
    """
    first = PAGE // len(lines[0]) + 5
    for ln in lines[:first]:
        print(ln, flush=True)
    for _ in range(1000):
        if pump._chars_out >= PAGE - len(lines[0]):
            break
        time.sleep(0.01)
    return first


def test_writes_past_the_limit_are_dropped_counted_and_said():
    lines = [f"line {i:04d} " + "x" * 90 for i in range(2000)]  # 200 KB against a 4 KB pipe
    got: list[bytes] = []
    with std_streams_on_a_small_pipe() as (r, w):
        pump = OutputPump(limit_chars=10 * PAGE).start()

        def write_lines():
            first = fill_the_pipe(pump, lines)
            for ln in lines[first:]:
                print(ln, flush=True)

        writer = threading.Thread(target=write_lines, daemon=True)
        writer.start()
        writer.join(30)
        written_unread = not writer.is_alive()
        reader = threading.Thread(target=lambda: got.append(read_all(r)), daemon=True)
        reader.start()
        closed = pump.close(timeout_s=30)
        os.close(w)  # end of file for the reader
        reader.join(30)
    assert written_unread, "the writes waited for the reader"
    assert closed and pump.n_dropped_lines > 0
    text = got[0].decode().splitlines()
    note = f"ssidlab: {pump.n_dropped_lines} output line(s) dropped here while the output was not read"
    assert text[-1].startswith(note)
    kept = text[:-1]
    # What was kept is the run's first lines, in order and whole; the rest was dropped.
    assert kept == lines[:len(kept)] and 0 < len(kept) == len(lines) - pump.n_dropped_lines


def test_lines_dropped_mid_run_are_said_where_they_are_missing():
    """A reader that stops, then reads again: the printout says at the gap how many lines it
    lacks, and goes on with the lines written after the reader caught up."""
    lines = [f"line {i:04d} " + "x" * 90 for i in range(400)]
    burst = 300  # 30 KB: the pipe's 4 KB, the queue's 16 KB, then dropped lines
    got: list[bytes] = []
    with std_streams_on_a_small_pipe() as (r, w):
        pump = OutputPump(limit_chars=4 * PAGE).start()
        for ln in lines[fill_the_pipe(pump, lines):burst]:
            print(ln, flush=True)
        assert pump.n_dropped_lines > 0
        n_gap = pump.n_dropped_lines
        reader = threading.Thread(target=lambda: got.append(read_all(r)), daemon=True)
        reader.start()
        for _ in range(3000):  # the reader reads again; wait until it has caught up
            if pump._chars_out >= pump._chars_in:
                break
            time.sleep(0.01)
        for ln in lines[burst:]:
            print(ln, flush=True)
        closed = pump.close(timeout_s=30)
        os.close(w)
        reader.join(30)
    assert closed and pump.n_dropped_lines == n_gap, "nothing is dropped once the reader reads"
    text = got[0].decode().splitlines()
    notes = [i for i, ln in enumerate(text) if ln.startswith("ssidlab:")]
    assert len(notes) == 1, text[-3:]
    gap = notes[0]
    assert text[gap].startswith(f"ssidlab: {n_gap} output line(s) dropped here")
    before, after = text[:gap], text[gap + 1:]
    assert before == lines[:len(before)] and len(before) == burst - n_gap
    assert after == lines[burst:]


def test_a_reader_gone_is_a_broken_pipe_for_the_run():
    """As on a plain stream (``ssidlab acquire ... | head``): the run stops, instruments safe."""
    raised = None
    with std_streams_on_a_small_pipe() as (r, _):
        pump = OutputPump().start()
        os.close(r)
        try:
            for _ in range(10_000):
                print("a line", flush=True)
                threading.Event().wait(0.001)
        except BrokenPipeError as exc:
            raised = exc
        finally:
            pump.close(timeout_s=5)
    assert isinstance(raised, BrokenPipeError)
