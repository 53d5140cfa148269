"""How a run file is replaced by a whole new file, never changed in its structure in place:
the file made under another name and linked to its own, the edited copy renamed over it, the
compact file that replaces it when the run ends, and the leftovers of replacements a killed
process did not finish.

A ``kill -9`` while HDF5 changes a file's structure (several writes) left files that could
not be resumed (``daq.storage``'s docstring says which); a file renamed or linked whole is
there entirely or not at all. :class:`ReplacedByCopy` is a base class of
:class:`daq.storage.RunFile` and works on its open file (``path``, ``f``, ``acq``,
``n_done``); it is not used on its own.

Split from ``daq.storage`` (which passed 500 lines) along the seam between what is written
into the open run file and how the file is replaced; behaviour unchanged.
"""

from __future__ import annotations

import errno
import glob
import os
import time
from collections.abc import Callable
from pathlib import Path

import h5py

from ssid.errors import InputError
from ssid.frf import FRFData
from ssid.io import read_frf, write_frf

__all__ = ["ReplacedByCopy"]


def _finishing(final: Path) -> bool:
    """Whether the process named in a replacement's name (``.RUN.h5.<pid>.final``, ``.edit``
    or ``.new``, :func:`_temp_name`) still runs: between closing the run file (its lock gone) and
    renaming its replacement over it, a run is still writing, and a resume that opened the run
    file then must not delete its copy (the run then failed on its rename)."""
    pid = final.name.rsplit(".", 2)[-2]
    if not pid.isdigit() or int(pid) == os.getpid():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


def _check_compact(path: Path, frf: FRFData, run_path: Path) -> None:
    """Read the compact file ``path`` back before it replaces the run file ``run_path``: what
    HDF5 failed to write while closing it is only printed, not raised, and the run file is
    the measurement."""
    try:
        back = read_frf(path)
        with h5py.File(path, "r") as g:
            int(g["acq/n_done"][0])
        if back.n_freq != frf.n_freq:
            raise InputError(f"{back.n_freq} of {frf.n_freq} lines")
    except (InputError, OSError, RuntimeError, KeyError) as exc:
        raise OSError(f"{run_path}: the finished file did not read back whole ({exc}); the run file is kept, "
                      f"and `ssidlab acquire --resume {run_path}` finishes it (a full disk?)") from exc


def _remove_stale(path: Path, what: str) -> None:
    """Remove the replacements of ``path`` (:func:`_temp_name`) a killed run left half-written.
    One whose process still runs is that process's, renamed over the run file after it closed
    it."""
    for stale in path.parent.glob(f".{glob.escape(path.name)}.*.{what}"):
        if not _finishing(stale):
            stale.unlink(missing_ok=True)


def _link_new(tmp: Path, path: Path) -> None:
    """Give the whole new file ``tmp`` its name ``path``. A link, not a rename: another run
    that created the same name in the meantime must make this one fail (FileExistsError), not
    lose its file. A file system without hard links gets a rename after a last check."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.ENOSYS):
            raise
        if path.exists():
            raise FileExistsError(errno.EEXIST, "exists", str(path)) from None
        os.rename(tmp, path)


def _temp_name(path: Path, pid: int | str, what: str) -> Path:
    """The name of a file that becomes the run file ``path`` when it is whole: the new file
    (``what`` "new"), the compact file ("final") or an edited copy ("edit"), by process ``pid``."""
    return path.with_name(f".{path.name}.{pid}.{what}")


class ReplacedByCopy:
    """The replacements of an open :class:`~daq.storage.RunFile`: a change of structure
    (:meth:`_edit_in_copy`) and the run's end (:meth:`finalize`)."""

    def _edit_in_copy(self, edit: Callable[[h5py.File], None]) -> None:
        """Change the file's structure (a dataset created or replaced) in a copy of it, then
        rename the copy over it.

        HDF5 links a new object into a group with several writes (the group's name heap, its
        symbol-table node, the object's header, at their own places in the file), and a
        ``kill -9`` between them left ``/acq`` unreadable: a resumed run killed while it
        replaced ``meta_json`` could no longer be resumed, nor its records read. The copy is
        whole or absent when the file is renamed. This happens at a session's start (its
        metadata, its noise floor) and at a random run's first average, before anything of
        the session is measured; it costs a copy of the file, raw samples included."""
        tmp = _temp_name(self.path, os.getpid(), "edit")
        self.f.flush()
        try:
            with h5py.File(tmp, "x") as g:
                for k in self.f.attrs:
                    g.attrs.create(k, self.f.attrs[k], dtype=self.f.attrs.get_id(k).dtype)
                for name in self.f:
                    self.f.copy(self.f[name], g, name=name)
                edit(g)
                g.flush()  # a full disk raises here; at close HDF5 would only print it
            with h5py.File(tmp, "r") as g:
                if int(g["acq/n_done"][0]) != self.n_done:
                    raise OSError("the copy's commit counter differs")
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        self.f.close()
        try:
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
            self.f = h5py.File(self.path, "r+")
            self.acq = self.f["acq"]

    # ------------------------------------------------------------------ finish
    def finalize(self, frf: FRFData, state: str = "complete") -> None:
        """Replace the run file by the compact FRF file plus ``/acq``, atomically; closes.

        The final ``state`` is written into the compact file only: until the rename, the run
        file on disk is the running one, so a crash while the compact file is being written
        leaves a file that a resume finishes (a "complete" run file in the running layout
        would never be made compact, and would hold the unmeasured lines as NaN rows).
        """
        tmp = _temp_name(self.path, os.getpid(), "final")
        self.f.flush()
        try:
            write_frf(tmp, frf)
            with h5py.File(tmp, "a") as g:
                self.f.copy(self.acq, g, name="acq")
                g["acq"].attrs["state"] = state
                g["acq"].attrs["finished_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
                # A write that fails (a full disk) raises here; at the close below HDF5 would
                # only print it, and the broken copy would replace the run file.
                g.flush()
            _check_compact(tmp, frf, self.path)
            self.f.close()
            os.replace(tmp, self.path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
