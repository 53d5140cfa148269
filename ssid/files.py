"""Files written whole or not at all."""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["written_atomically"]

# Errors of a write that ran out of room: raised by the write to the temporary file (an
# ordinary write's OSError carries no file name), so they are the target's.
_NO_ROOM = {errno.ENOSPC, errno.EFBIG, errno.EDQUOT}


@contextmanager
def written_atomically(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path`` for the block to write; renamed onto ``path`` when
    the block ends without error, removed otherwise, so that a failed or interrupted write
    never leaves a half file under the name asked for (nor replaces a good one).

    A file that cannot be created or renamed raises ``OSError`` whose message names ``path``,
    not the temporary name the user never gave; so does a ``path`` that exists and is not a
    regular file (a device, a pipe), which the rename would replace.
    """
    target = Path(path)
    if target.exists() and not target.is_file() and not target.is_dir():
        # The rename would put a regular file in place of the device, pipe or socket (run as
        # root with --out /dev/null: the system's /dev/null), not write to it.
        raise OSError(f"{target}: cannot write (it exists and is not a regular file: a device, a pipe "
                      "or a socket; give the name of a file)")
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        os.replace(tmp, target)
    except OSError as exc:
        _remove(tmp)
        about_tmp = (exc.filename is not None and Path(exc.filename) == tmp) or exc.errno in _NO_ROOM
        if about_tmp or os.fspath(tmp) in str(exc):  # h5py names the file in its message only
            why = os.strerror(exc.errno) if exc.errno else (exc.strerror or str(exc))
            raise OSError(f"{target}: cannot write ({why})") from exc
        raise
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: Path) -> None:
    # Never raises: a temporary file that could not be created may sit where none can be
    # (under a file, in a directory gone), and the error that matters is the write's.
    try:
        tmp.unlink(missing_ok=True)
    except OSError:
        pass
