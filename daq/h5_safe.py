"""HDF5 details that keep a run file whole through a ``kill -9``.

:func:`index_chunks` builds a dataset's chunk index before anything is measured.

:func:`extend_allocation_to_file_end` restores a run file's end of allocation after a kill
inside a flush. An HDF5 file's superblock
holds the address where the file's allocated space ends (its EOA), and HDF5 refuses to
read at or past it ("addr overflow"). A line that appends raw samples allocates new chunks
past the EOA. At the flush, HDF5 writes the chunks, then the headers and chunk indexes that
point to them, and the superblock with the new EOA last: a kill just before that last write
left a file whose indexes point past its EOA. The committed lines lie below the old EOA and
are whole, but a resume reads the raw samples' last row, and a resumed session's first
append reads the chunk it continues: both failed, and the file was refused as damaged.
Worse, closing a file opened for writing cuts it to its EOA, which lost those chunks for
good.

HDF5's own repair is ``h5clear --increment`` (``H5Fincrement_filesize``): the EOA set to
the file's end. h5py offers neither, so :func:`extend_allocation_to_file_end` writes the
superblock's 8 bytes itself, for the superblock versions 0 and 1 (the HDF5 file format
specification, "Superblock") that run files are written with.
"""

from __future__ import annotations

import fcntl
import os
import struct
from pathlib import Path

import h5py
import numpy as np

__all__ = ["extend_allocation_to_file_end", "index_chunks"]

_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: Byte offset of the end-of-file address in superblock versions 0 and 1 (version 1 adds 4
#: bytes of indexed-storage settings before the addresses), with 8-byte addresses.
_EOA_AT = {0: 40, 1: 44}


def extend_allocation_to_file_end(path: str | Path) -> bool:
    """Set the superblock's end of allocation to the file's size where it is smaller.

    Bytes past the old end are what the killed process wrote and the file's indexes may
    point to; where nothing points to them, taking them in costs their space only. Files
    with another superblock version, a user block or addresses other than 8 bytes are left
    as they are, as is a file another process holds open for writing (HDF5's lock).

    Returns
    -------
    bool
        Whether the superblock was changed; False also for a file this process may not
        write (opening it for resuming then says why).
    """
    try:
        fh = open(path, "r+b")
    except OSError:
        return False
    with fh:
        try:  # the lock HDF5 takes for writing: a live run's file is not touched
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False
        head = fh.read(64)
        if len(head) < 64 or head[:8] != _SIGNATURE or head[8] not in _EOA_AT or head[13] != 8:
            return False
        at = _EOA_AT[head[8]]
        (base,) = struct.unpack_from("<Q", head, at - 16)
        (eoa,) = struct.unpack_from("<Q", head, at)
        size = os.fstat(fh.fileno()).st_size
        if base != 0 or eoa >= size:
            return False
        fh.seek(at)
        fh.write(struct.pack("<Q", size))
        return True


def index_chunks(ds: h5py.Dataset) -> None:
    """Build the chunk index of a dataset of no rows now, while nothing is measured: HDF5
    builds it at the first write, as several writes in the first line's flush (the index's
    nodes, the dataset's header), and a ``kill -9`` between them left a file that could not
    be resumed. A row written and cut again leaves the (empty) index in place; later lines
    add their chunks to it."""
    ds.resize(1, axis=0)
    ds[0] = np.zeros(ds.shape[1:], ds.dtype)
    ds.resize(0, axis=0)
