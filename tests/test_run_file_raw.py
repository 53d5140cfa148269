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

import h5py
import numpy as np
import pytest
from test_daq_helpers import cli, killed_at_write, sine_setup

from daq.raw_store import CHUNK_ROWS, SEGMENT_ROWS, raw_rows
from daq.storage import RunFile

ROOT = Path(__file__).resolve().parents[1]
NCH = 3

#: The child: ``prep PATH N ROWS`` makes a run file with N committed lines of ROWS raw
#: samples each, ``step PATH N ROWS`` reopens it and commits N more.
CHILD = """
import sys
import h5py
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
    killed = _child(tmp_path, args[0], str(run), *args[1:], strace=killed_at_write(run, nth))
    assert killed.returncode != 0, "the child was not killed"


def _superblock_eoa(path: Path) -> int:
    """The end-of-allocation address in a version 0 superblock."""
    head = path.read_bytes()[:48]
    assert head[8] == 0
    return struct.unpack_from("<Q", head, 40)[0]


def _raw_rows(rf: RunFile, k: int, rows: int) -> np.ndarray:
    return raw_rows(rf.acq["raw"], int(rf.acq["raw/offset"][k]), rows)


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


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace to kill the child inside a write")
def test_a_kill_while_the_chunk_index_would_split_keeps_the_committed_samples(tmp_path):
    """HDF5's chunk index holds 64 chunks in a node; the next chunk split it, and the flush
    wrote the rewritten node before the new one. Killed between (in the line that passes
    64 chunks, after its samples' writes), the index of the samples committed before was
    lost and the run could not be resumed. Raw samples are now kept in segments of 64
    chunks, whose index never splits."""
    rows = 40000
    run = tmp_path / "run.h5"
    before = SEGMENT_ROWS // rows  # lines committed before the one that passes 64 chunks
    assert _child(tmp_path, "prep", str(run), str(before), str(rows)).returncode == 0
    base = tmp_path / "base.h5"
    shutil.copy(run, base)
    writes = _writes(tmp_path, run, "step", "1", str(rows))
    # The flush's metadata: the writes after the line's last chunk, up to the superblock.
    last_chunk = max(i for i, (size, _) in enumerate(writes) if size == CHUNK_ROWS * NCH * 4)
    superblock = next(i for i, w in enumerate(writes) if w == (96, 0) and i > last_chunk)
    for nth in range(last_chunk + 2, superblock + 2):
        shutil.copy(base, run)
        _kill_at(tmp_path, run, nth, "step", "1", str(rows))
        rf = RunFile.open(run)
        try:
            for k in range(rf.n_done):
                np.testing.assert_array_equal(_raw_rows(rf, k, rows), _expected(k, rows), err_msg=f"kill at {nth}")
        finally:
            rf.close()


def test_raw_samples_beyond_the_files_segments_are_kept_in_more(tmp_path):
    """A run whose records outgrow the segments the file was made with gets more in an
    edited copy; every dataset of samples stays within one index node (64 chunks), and the
    records read back whole across segment boundaries."""
    run = tmp_path / "run.h5"
    rf = RunFile.create(run, kind="stepped_sine", setup_text="", setup_sha256="", freq_hz=np.arange(1.0, 5.0),
                        outputs=["1+Z"], inputs=["1+Z"], reactions=[], channel_names=["a", "b", "c"], meta={},
                        attrs={}, raw_time=True)
    rows = SEGMENT_ROWS * 3 // 4 + 1  # lines straddle segment boundaries
    try:
        for k in range(4):
            rf.append_raw(_expected(k, rows).T)
            rf.commit(k + 1)
        raw = rf.acq["raw"]
        chunks = {name: ds.id.get_num_chunks() for name, ds in raw.items() if name != "offset"}
        assert max(chunks.values()) <= 64 and sum(chunks.values()) == -(-4 * rows // CHUNK_ROWS), chunks
        for k in range(4):
            np.testing.assert_array_equal(_raw_rows(rf, k, rows), _expected(k, rows))
    finally:
        rf.close()


def test_a_stepped_sine_run_keeps_every_dwell_record_in_segments(tmp_path):
    """``raw_time = true``, end to end on the simulated lab: the file is made with the
    segments the run's longest dwells could fill, each sub-line's record is the length of
    its dwell, and the finished file keeps them."""
    setup = tmp_path / "s.toml"
    setup.write_text(sine_setup(n_lines=2, refine=1).replace('file = "run.h5"', 'file = "run.h5"\nraw_time = true'))
    run = tmp_path / "run.h5"
    status, err = cli([str(setup), "--out", str(run), "--sim", "--quiet"])
    assert status == 0, err
    rf = RunFile(run, h5py.File(run, "r"))
    try:
        raw, rec = rf.acq["raw"], rf.records()
        segments = [name for name in raw if name.startswith("samples_")]
        # 2 lines x 1 shaker x 10 s (max_dwell_s's default) x 4096 samples/s, 262144 rows a segment
        assert len(segments) == 1 and "samples" not in raw
        ok = rec["status"] == 0
        assert ok.any()
        offsets = raw["offset"][()]
        lengths = np.diff(np.append(offsets[ok], sum(raw[s].shape[0] for s in segments)))
        np.testing.assert_array_equal(lengths, np.round(rec["dwell_s"][ok] * 4096).astype(int))
        for k, n in zip(np.flatnonzero(ok), lengths):
            assert np.isfinite(raw_rows(raw, int(offsets[k]), int(n))).all()
    finally:
        rf.close()


def test_a_run_file_this_process_may_not_write_is_left_to_the_resume_to_refuse(tmp_path, monkeypatch):
    """The end-of-allocation repair opens the file for writing before HDF5 does; a file
    it may not open (permissions) is left as it is, for the resume's own message, not a
    PermissionError traceback."""
    import daq.h5_safe as h5_safe

    def refused(*args, **kw):
        raise PermissionError(13, "Permission denied")

    run = tmp_path / "run.h5"
    assert _child(tmp_path, "prep", str(run), "1", "100").returncode == 0
    monkeypatch.setattr(h5_safe, "open", refused, raising=False)
    assert h5_safe.extend_allocation_to_file_end(run) is False
