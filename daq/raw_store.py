"""The dwell records' raw time samples in a run file (``/acq/raw``), kept so that
appending them never splits a chunk index.

HDF5 (in the default file format run files use) indexes a chunked dataset's chunks with a
B-tree whose nodes hold 64 chunks. The chunk after a full node splits it: part of its
entries move to a new node at the end of the file, and the flush writes the old node,
rewritten without them, before the new one (HDF5 writes its metadata in address order).
A ``kill -9`` between the two writes lost the index of samples committed before, and the
run could not be resumed: measured with strace fault injection, 1 or 2 of the ~54 writes
of the line in which a node split, for the first time after 64 chunks of 4096 rows and then
every 57 or so.

So the samples are kept in segments, ``samples_00000``, ``samples_00001``, ..., of at most
:data:`SEGMENT_ROWS` rows, the 64 chunks one index node holds, each with its index built
when it is made: a segment's index is one node that never splits. Together the segments
are one array of rows (global row ``r`` is row ``r % SEGMENT_ROWS`` of segment
``r // SEGMENT_ROWS``), filled in order; ``offset[k]`` is the global first row of
sub-line ``k``'s record. The file is made with the segments the run's longest dwells could
fill (at most :data:`MAX_SEGMENTS_AT_CREATION`); a run that needs more gets them in an
edited copy of the file (structure, :meth:`daq.storage.RunFile._edit_in_copy`).
Files from before keep one ``samples`` dataset and are appended to as they were.
"""

from __future__ import annotations

import math

import h5py
import numpy as np

from daq.h5_safe import index_chunks

__all__ = ["CHUNK_ROWS", "SEGMENT_ROWS", "add_segments", "append_raw", "create_raw", "raw_rows",
           "segments_missing"]

#: Rows of one chunk of raw samples (float32, all channels).
CHUNK_ROWS = 4096
#: Rows of one segment: the chunks one node of HDF5's chunk index holds (2 x 32, its default).
SEGMENT_ROWS = 64 * CHUNK_ROWS
#: Segments made with the file at most (each costs about 3 kB of an empty index and header);
#: a run that fills them gets more in an edited copy.
MAX_SEGMENTS_AT_CREATION = 1024


def _segment_name(j: int) -> str:
    return f"samples_{j:05d}"


def _n_segments(raw: h5py.Group) -> int:
    return sum(1 for name in raw if name.startswith("samples_"))


def create_raw(acq: h5py.Group, nch: int, rows_expected: int) -> None:
    """``/acq/raw`` with the segments ``rows_expected`` rows fill (at least one)."""
    raw = acq.create_group("raw")
    index_chunks(raw.create_dataset("offset", shape=(0,), maxshape=(None,), chunks=(4096,), dtype="i8"))
    add_segments(raw, nch, min(MAX_SEGMENTS_AT_CREATION, max(1, math.ceil(rows_expected / SEGMENT_ROWS))))


def add_segments(raw: h5py.Group, nch: int, n: int) -> None:
    """``n`` more empty segments after those ``raw`` holds."""
    have = _n_segments(raw)
    for j in range(have, have + n):
        index_chunks(raw.create_dataset(_segment_name(j), shape=(0, nch), maxshape=(SEGMENT_ROWS, nch),
                                        chunks=(CHUNK_ROWS, nch), dtype="f4"))


def _end(raw: h5py.Group) -> int:
    """Global rows written so far: segments fill in order, so the first one not full ends
    them (found by bisection: a long run has hundreds)."""
    n = _n_segments(raw)
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if raw[_segment_name(mid)].shape[0] == SEGMENT_ROWS:
            lo = mid + 1
        else:
            hi = mid
    return lo * SEGMENT_ROWS + (raw[_segment_name(lo)].shape[0] if lo < n else 0)


def segments_missing(raw: h5py.Group, n_rows: int) -> int:
    """Segments to add before ``n_rows`` more rows fit: 0, or at least as many as there are
    (the copy that adds them costs the whole file, so their number doubles)."""
    if "samples" in raw:  # a file from before segments
        return 0
    have = _n_segments(raw)
    short = math.ceil((_end(raw) + n_rows) / SEGMENT_ROWS) - have
    return 0 if short <= 0 else max(short, have)


def append_raw(raw: h5py.Group, k: int, data: np.ndarray) -> None:
    """Sub-line ``k``'s record ``data`` (n_ch, n) after the rows written so far (those of a
    killed line past the last commit stay, unreferenced)."""
    rows = np.asarray(data, np.float32).T
    o = raw["offset"]
    if "samples" in raw:  # a file from before segments: one dataset
        s = raw["samples"]
        o.resize(k + 1, axis=0)
        o[k] = s.shape[0]
        s.resize(s.shape[0] + rows.shape[0], axis=0)
        s[-rows.shape[0]:] = rows
        return
    start = _end(raw)
    o.resize(k + 1, axis=0)
    o[k] = start
    i = 0
    while i < rows.shape[0]:
        j, r = divmod(start + i, SEGMENT_ROWS)
        seg = raw[_segment_name(j)]
        take = min(rows.shape[0] - i, SEGMENT_ROWS - r)
        seg.resize(r + take, axis=0)
        seg[r:] = rows[i:i + take]
        i += take


def raw_rows(raw: h5py.Group, first: int, n: int) -> np.ndarray:
    """Global rows ``first`` to ``first + n`` of the raw samples, (n, n_ch) float32."""
    if "samples" in raw:
        return raw["samples"][first:first + n]
    out, r, stop = [], first, first + n
    while r < stop:
        j, i = divmod(r, SEGMENT_ROWS)
        take = min(stop - r, SEGMENT_ROWS - i)
        out.append(raw[_segment_name(j)][i:i + take])
        r += take
    return np.concatenate(out) if out else np.zeros((0, raw[_segment_name(0)].shape[1]), np.float32)
