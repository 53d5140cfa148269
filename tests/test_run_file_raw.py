"""A run file's raw time samples under a ``kill -9``: each test writes lines through
:class:`daq.storage.RunFile` in a child process, kills it at a chosen write to the file
(strace fault injection), and checks that a resume keeps every committed line's samples."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from daq.storage import RunFile

ROOT = Path(__file__).resolve().parents[1]
NCH = 3

#: The child: ``prep PATH N ROWS`` makes a run file with N committed lines of ROWS raw
#: samples each, ``step PATH N ROWS`` reopens it and commits N more.
CHILD = """
import sys
import numpy as np
from daq.storage import RunFile, SINE_FIELDS, STATUS_OK

mode, path, n, rows = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
nch = {nch}

def write(rf, k):
    row = {{name: (np.full(nch, k + 1.0) if per else k + 1) for name, (_, per) in SINE_FIELDS.items()}}
    row.update(grid_index=k, pattern=0, status=STATUS_OK, reason="", X=np.full(nch, k + 1 + 0j))
    rf.append_record(row)
    rf.write_line(k, np.full((1, 1), k + 1j), np.ones((1, 1)), np.ones((1, 1)), np.ones((1, 1), bool), None)
    rf.append_raw(np.arange(nch * rows, dtype=np.float32).reshape(nch, rows) % 1000 + 1000 * k)
    rf.commit(k + 1)

if mode == "prep":
    rf = RunFile.create(path, kind="stepped_sine", setup_text="", setup_sha256="", freq_hz=np.arange(1.0, 41.0),
                        outputs=["1+Z"], inputs=["1+Z"], reactions=[], channel_names=["a", "b", "c"][:nch],
                        meta={{}}, attrs={{}}, raw_time=True)
else:
    rf = RunFile.open(path)
for k in range(rf.n_done, rf.n_done + n):
    write(rf, k)
rf.close()
""".format(nch=NCH)


def _expected(k: int, rows: int) -> np.ndarray:
    """Line ``k``'s raw samples as the child writes them, (rows, nch)."""
    return (np.arange(NCH * rows, dtype=np.float32).reshape(NCH, rows) % 1000 + 1000 * k).T


def _child(tmp_path: Path, *args: str, strace: list[str] | None = None) -> subprocess.CompletedProcess:
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    return subprocess.run([*(strace or []), sys.executable, str(script), *args], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))


def _writes(tmp_path: Path, run: Path, *args: str) -> list[tuple[int, int]]:
    """(size, offset) of each write the child makes to ``run``, the child run on a copy."""
    copy, log = tmp_path / "copy.h5", tmp_path / "writes.log"
    shutil.copy(run, copy)
    done = _child(tmp_path, args[0], str(copy), *args[1:],
                  strace=["strace", "-f", "-o", str(log), "-P", str(copy), "-e", "trace=pwrite64"])
    assert done.returncode == 0, done.stderr
    writes = []
    for line in log.read_text().splitlines():
        if "pwrite64(" in line and "= " in line:
            size, offset = line.rsplit(")", 1)[0].rsplit(", ", 2)[1:]
            writes.append((int(size), int(offset)))
    return writes


def _kill_at(tmp_path: Path, run: Path, nth: int, *args: str) -> None:
    killed = _child(tmp_path, args[0], str(run), *args[1:],
                    strace=["strace", "-f", "-o", "/dev/null", "-P", str(run), "-e", "trace=pwrite64", "-e",
                            f"inject=pwrite64:signal=KILL:when={nth}"])
    assert killed.returncode != 0, "the child was not killed"


def _superblock_eoa(path: Path) -> int:
    """The end-of-allocation address in a version 0 superblock."""
    head = path.read_bytes()[:48]
    assert head[8] == 0
    return struct.unpack_from("<Q", head, 40)[0]


def _raw_rows(rf: RunFile, k: int, rows: int) -> np.ndarray:
    start = int(rf.acq["raw/offset"][k])
    return rf.acq["raw/samples"][start:start + rows]


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace to kill the child inside a write")
def test_a_kill_before_the_superblocks_new_end_keeps_the_run_resumable(tmp_path):
    """A line's new raw chunks lie past the file's end of allocation (EOA); HDF5 writes the
    superblock with the new EOA last in the flush. Killed just before, the chunk index
    pointed past the EOA: the resume read the raw samples' last row and refused the file
    as damaged, and its close cut the file at the old EOA, losing the chunks for good.
    The resume now moves the EOA to the file's end first."""
    rows = 40000  # about 10 chunks of 4096 rows a line: every line allocates chunks
    run = tmp_path / "run.h5"
    assert _child(tmp_path, "prep", str(run), "2", str(rows)).returncode == 0
    writes = _writes(tmp_path, run, "step", "1", str(rows))
    size = run.stat().st_size
    first_new = next(i for i, (_, off) in enumerate(writes) if off >= size)
    superblock = next(i for i, w in enumerate(writes) if w == (96, 0) and i > first_new)
    _kill_at(tmp_path, run, superblock + 1, "step", "1", str(rows))
    assert _superblock_eoa(run) < run.stat().st_size, "the kill point no longer leaves the EOA behind"

    rf = RunFile.open(run)
    try:
        assert rf.n_done == 2
        for k in range(2):
            np.testing.assert_array_equal(_raw_rows(rf, k, rows), _expected(k, rows))
    finally:
        rf.close()
    # The resumed session appends into the chunk the killed line had begun.
    assert _child(tmp_path, "step", str(run), "1", str(rows)).returncode == 0
    rf = RunFile.open(run)
    try:
        assert rf.n_done == 3
        np.testing.assert_array_equal(_raw_rows(rf, 2, rows), _expected(2, rows))
    finally:
        rf.close()
