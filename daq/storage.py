"""The run file: one HDF5 file per run that never loses a completed line.

Layout (``docs/acquisition.md``): the contract's FRF datasets at the root (readable by
:func:`ssid.io.read_frf` at every moment of the run), and under ``/acq`` everything the run
needs to continue or to be audited: the setup file's text and SHA-256, metadata
(instrument identities, software version, timestamps, channels), and the *records* - one
row per measured sub-line (stepped sine) in acquisition order, or the running spectral sums
(random).

Crash safety without SWMR: SWMR leaves a file that only SWMR readers can open after a
``kill -9`` (the superblock's "open for writing" flag stays set), so the file is written in
the default HDF5 format and flushed after every line instead. A line is written in this
order: record row and contract rows, ``flush()``, then the commit counter ``/acq/n_done``,
then ``flush()`` again. HDF5 writes what one flush holds in an order of its own (``n_done``'s
8 bytes went out before the records' new extent: a ``kill -9`` inside that flush left a
counter past the records, and the file could not be resumed), so the counter gets a flush of
its own after everything it counts is on disk. After a crash, rows beyond ``n_done`` are
ignored (and trimmed on resume).

Nor does HDF5 change a file's structure (a new dataset, group or attribute, a dataset's
first space, a chunk index) in one write, and a kill between those writes damaged the file:
inside the first line's flush, or while a resume replaced ``meta_json``, with it the records
of every line committed before. So a line changes no structure. :meth:`RunFile.create` builds
the file under another name and links it to its own when whole, with the contract datasets'
space written and the records' chunk indexes built; what a session adds (its metadata, its
noise floor, a random run's first sums) is made in a copy renamed over the file
(:meth:`RunFile._edit_in_copy`). A random run's sums are overwritten in place at every
average, so they are kept in two sets, written in turn (``daq.random_run``). Raw time samples
are stored without compression: a compressed chunk is rewritten whole, at a new place in the
file, when a line appends to it, and a kill inside that write lost the samples of lines
committed before (HDF5 "filter returned failure during read"); an uncompressed chunk is
rewritten in place with the same bytes where it holds them; they are kept in segments
whose chunk indexes never split (:mod:`daq.raw_store`). This holds against a killed
process (what it wrote is in the operating system's cache); it does not order writes against
a power cut, for which nothing here calls ``fsync``.

When the run ends, :meth:`RunFile.finalize` writes the compact FRF file (only measured
lines) with :func:`ssid.io.write_frf` under a temporary name, copies ``/acq`` into it and
renames it over the run file - so the finished file replaces the running one atomically.
The replacements (the new file linked, the edited copy, the compact file, a killed process's
leftovers) are in :mod:`daq.run_file_replace`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

from daq.h5_safe import extend_allocation_to_file_end, index_chunks
from daq.raw_store import add_segments, append_raw, create_raw, segments_missing
from daq.run_file_replace import (  # noqa: F401
    ReplacedByCopy,
    _check_compact,
    _finishing,
    _link_new,
    _remove_stale,
    _temp_name,
)
from ssid.errors import InputError
from ssid.io import label_frf_units

__all__ = ["RunFile", "STATUS_ABORTED", "STATUS_OK", "SINE_FIELDS", "peek_run_file"]

# _check_compact and _finishing (imported above, hence the noqa) were defined here before the
# file replacements moved to daq.run_file_replace; they stay importable here.
STATUS_OK, STATUS_ABORTED = 0, 1
#: Rows of one chunk of a stepped-sine record field. HDF5's chunk index holds 64 chunks in a
#: node, and the chunk after a full one splits it in writes a kill can come between
#: (:mod:`daq.raw_store`): 1024-row chunks put the first split past 65536 sub-lines (64-row
#: ones, before, at 4096), at a flush of at most one chunk per field a line.
RECORD_CHUNK_ROWS = 1024

#: Per-sub-line record of a stepped-sine run: name -> (dtype, per channel?).
SINE_FIELDS = {
    "grid_index": ("i4", False), "pattern": ("i2", False), "freq_hz": ("f8", False),
    "drive_vpp": ("f8", False), "status": ("i1", False), "settle_s": ("f8", False),
    "dwell_s": ("f8", False), "transient": ("f8", False), "decay": ("f8", False),
    "wall_time": ("f8", False),
    "X": ("c16", True), "X_var": ("f8", True), "thd": ("f8", True), "reason": ("S320", False),
    "X_transient": ("f8", True),
}
_STR = h5py.string_dtype()


def peek_run_file(path: str | Path) -> tuple[str | None, int] | None:
    """``(state, n_done)`` of a run file, read-only (the file is not trimmed or touched):
    ``state`` None and ``n_done`` 0 where ``/acq`` lacks them; None when there is no readable
    HDF5 file with ``/acq`` at ``path``."""
    try:
        with h5py.File(path, "r", locking=False) as f:  # a running acquisition holds the lock
            acq = f.get("acq")
            if not isinstance(acq, h5py.Group):
                return None
            state, n_done = acq.attrs.get("state"), acq.get("n_done")
            return (None if state is None else str(state)), (0 if n_done is None else int(n_done[0]))
    except Exception:  # noqa: BLE001 -- no file, not HDF5, a broken /acq: nothing to report
        return None


class _Inconsistent(ValueError):
    """A run file that HDF5 reads but that contradicts how run files are written."""


class RunFile(ReplacedByCopy):
    """An open run file (create with :meth:`create`, reopen with :meth:`open`)."""

    def __init__(self, path: str | Path, f: h5py.File) -> None:
        self.path = Path(path)
        self.f = f
        self.acq = f["acq"]

    # ------------------------------------------------------------------ create / open
    @classmethod
    def create(cls, path: str | Path, *, kind: str, setup_text: str, setup_sha256: str,
               freq_hz: np.ndarray, outputs: list[str], inputs: list[str], reactions: list[str],
               channel_names: list[str], meta: dict, attrs: dict, raw_time: bool = False,
               raw_rows_expected: int = 0) -> RunFile:
        """A new run file with the contract view over ``freq_hz`` (nothing measured yet), and
        ``/acq/raw`` where the run keeps its dwell records (``raw_time``), with room for
        ``raw_rows_expected`` rows (:mod:`daq.raw_store`)."""
        path = Path(path)
        exists = f"{path}: exists already (use --resume to continue it, or another name)"
        if path.exists():
            raise InputError(exists)
        _remove_stale(path, "new")
        # Built under another name and linked to its own when whole: a kill -9 while HDF5
        # writes a new file's structure left a file by the run's name that was no HDF5 file
        # or could not be opened, and a resume could not tell that nothing had been measured.
        tmp = _temp_name(path, os.getpid(), "new")
        try:
            f = h5py.File(tmp, "x")
        except OSError as exc:
            raise OSError(f"{path}: cannot create the run file ({exc})") from exc
        try:
            nf, no, ni, nr = len(freq_hz), len(outputs), len(inputs), len(reactions)
            for k, v in attrs.items():
                f.attrs[k] = v
            f.attrs["format"] = "ssidlab-frf"
            f.attrs["format_version"] = 1
            f.attrs["quantity"] = "accelerance"
            f.create_dataset("freq_hz", data=np.asarray(freq_hz, float))
            f.create_dataset("H", shape=(nf, no, ni), dtype="c16", fillvalue=complex(np.nan, 0.0))
            f.create_dataset("valid", shape=(nf, no, ni), dtype=bool, fillvalue=False)
            f.create_dataset("coherence", shape=(nf, no, ni), dtype="f8", fillvalue=0.0)
            f.create_dataset("H_var", shape=(nf, no, ni), dtype="f8", fillvalue=0.0)
            f.create_dataset("outputs", data=outputs, dtype=_STR)
            f.create_dataset("inputs", data=inputs, dtype=_STR)
            if nr:
                f.create_dataset("H_reaction", shape=(nf, nr, ni), dtype="c16", fillvalue=0j)
                f.create_dataset("H_reaction_var", shape=(nf, nr, ni), dtype="f8", fillvalue=0.0)
                f.create_dataset("reactions", data=reactions, dtype=_STR)
            acq = f.create_group("acq")
            acq.attrs["kind"] = kind
            acq.attrs["setup_sha256"] = setup_sha256
            acq.attrs["state"] = "running"
            acq.create_dataset("setup_toml", data=setup_text, dtype=_STR)
            acq.create_dataset("meta_json", data=json.dumps(meta), dtype=_STR)
            acq.create_dataset("channels", data=channel_names, dtype=_STR)
            acq.create_dataset("n_done", data=np.zeros(1, "i8"))
            acq.create_dataset("line_done", shape=(nf,), dtype=bool, fillvalue=False)
            nch = len(channel_names)
            rec = acq.create_group("records")
            if kind == "stepped_sine":
                for name, (dt, per_ch) in SINE_FIELDS.items():
                    shape = (0, nch) if per_ch else (0,)
                    index_chunks(rec.create_dataset(name, shape=shape, maxshape=(None,) + shape[1:],
                                                    chunks=(RECORD_CHUNK_ROWS,) + shape[1:], dtype=dt))
            label_frf_units(f)
            if raw_time:
                create_raw(acq, nch, raw_rows_expected)
            # HDF5 gives a dataset of fill values its space at the first write: written
            # now, so that the first line's flush does not change the file's layout.
            for ds in (f["H"], f["valid"], f["coherence"], f["H_var"], acq["line_done"],
                       *((f["H_reaction"], f["H_reaction_var"]) if nr else ())):
                ds[...] = ds.fillvalue
            f.close()
            _link_new(tmp, path)
        except FileExistsError:
            raise InputError(exists) from None
        except OSError as exc:
            raise OSError(f"{path}: cannot create the run file ({exc})") from exc
        finally:
            if f.id.valid:
                f.close()
            tmp.unlink(missing_ok=True)
        return cls(path, h5py.File(path, "r+"))

    @classmethod
    def open(cls, path: str | Path) -> RunFile:
        """Reopen an unfinished run file for resuming; rows past the last commit are dropped."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such run file")
        if not h5py.is_hdf5(path):
            raise InputError(f"{path}: not an HDF5 file")
        extend_allocation_to_file_end(path)  # a kill inside a flush: before HDF5 cuts the file at its old end
        try:
            f = h5py.File(path, "r+")
        except OSError as exc:
            raise InputError(f"{path}: cannot open the run file for resuming ({exc})") from None
        try:
            if "acq" not in f or "n_done" not in f["acq"] or "setup_toml" not in f["acq"]:
                raise InputError(f"{path}: not an ssidlab run file (no /acq records)")
            rf = cls(path, f)
            rf._read_everything_resume_needs()
            if rf.state != "complete":  # the compact file: nothing is resumed from it
                rf._check_consistent()
            n = rf.n_done
            rec = rf.acq["records"]
            for name in rec:
                if rec[name].shape[0] > n and rec[name].maxshape[0] is None:
                    rec[name].resize(n, axis=0)
        except InputError:
            f.close()
            raise
        except _Inconsistent as exc:
            f.close()
            raise InputError(f"{path}: the run file is damaged and cannot be resumed ({exc})") from None
        except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
            # HDF5 reports a damaged file (a disk error, a copy cut short) only when the
            # damaged part is read. Read it all here, before a resume enables an amplifier.
            f.close()
            raise InputError(f"{path}: the run file is damaged and cannot be resumed "
                             f"({type(exc).__name__}: {exc})") from None
        _remove_stale(path, "final")
        _remove_stale(path, "edit")
        return rf

    def _read_everything_resume_needs(self) -> None:
        """Read what a resume reads (state, setup, metadata, committed records, the contract
        view, the stored arrays), so that a damaged file fails here; of the raw time samples,
        which can be large and are only appended to, the index and the last row."""
        _ = self.state, self.kind, self.setup_text, self.setup_sha256, self.meta, self.freq_hz
        n = self.n_done
        for ds in self.acq["records"].values():
            ds[:n]
        for name in ("H", "valid", "coherence", "H_var", "H_reaction", "H_reaction_var"):
            if name in self.f:
                self.f[name][()]
        self.acq["line_done"][()]
        for group in self.acq.values():
            if isinstance(group, h5py.Group) and group.name not in ("/acq/records", "/acq/raw"):
                for ds in group.values():
                    ds[()]
        raw = self.acq.get("raw")
        if isinstance(raw, h5py.Group):
            for ds in raw.values():
                if ds.shape[0]:
                    ds[-1]

    def _check_consistent(self) -> None:
        """Raise :class:`_Inconsistent` where the file contradicts how it is written: a commit
        counter past the records (a resume would append after zero rows), a record field or
        the grid's bookkeeping missing or of the wrong size, the metadata not an object,
        or a kept stepped-sine record with a non-finite or non-positive value where the
        schedule's replay computes with it. A crash cannot leave these; another program
        writing into the file, or damage HDF5 does not detect, can."""
        nf, n = self.freq_hz.shape[0], self.n_done
        if not isinstance(self.meta, dict):
            raise _Inconsistent("/acq/meta_json is not a JSON object")
        if self.acq["line_done"].shape != (nf,) or self.f["H"].shape[0] != nf:
            raise _Inconsistent(f"/acq/line_done or /H does not have the grid's {nf} lines")
        rec = self.acq["records"]
        if n < 0 or any(ds.shape[0] < n for ds in rec.values()):
            raise _Inconsistent(f"/acq/n_done is {n}, but the records hold "
                                f"{min((ds.shape[0] for ds in rec.values()), default=0)} rows")
        if self.kind != "stepped_sine":
            return
        nch = self.acq["channels"].shape[0]
        for name, (_, per_ch) in SINE_FIELDS.items():
            if name == "X_transient" and name not in rec:  # files from before it was kept
                continue
            if name not in rec:
                raise _Inconsistent(f"record field {name!r} is missing")
            if per_ch and rec[name].shape[1:] != (nch,):
                raise _Inconsistent(f"record field {name!r} does not have one value per channel ({nch})")
        ok = rec["status"][:n] == STATUS_OK
        kept = {name: rec[name][:n][ok] for name in ("freq_hz", "drive_vpp", "settle_s", "dwell_s", "X", "X_var")}
        grid = rec["grid_index"][:n]
        if np.any((grid < 0) | (grid >= nf)):
            raise _Inconsistent(f"a record's grid line is outside the grid's {nf} lines")
        for name, v in kept.items():
            bad = ~np.isfinite(v)
            if name == "freq_hz":
                bad |= v <= 0
            elif name != "X":  # times, drives and variances; X is complex
                bad |= v < 0
            if np.any(bad):
                raise _Inconsistent(f"a kept record's {name!r} is not finite or out of range")

    # ------------------------------------------------------------------ properties
    @property
    def kind(self) -> str:
        return str(self.acq.attrs["kind"])

    @property
    def state(self) -> str:
        return str(self.acq.attrs["state"])

    @property
    def setup_text(self) -> str:
        v = self.acq["setup_toml"][()]
        return v.decode("utf-8") if isinstance(v, bytes) else str(v)

    @property
    def setup_sha256(self) -> str:
        return str(self.acq.attrs["setup_sha256"])

    @property
    def n_done(self) -> int:
        return int(self.acq["n_done"][0])

    @property
    def meta(self) -> dict:
        v = self.acq["meta_json"][()]
        return json.loads(v.decode("utf-8") if isinstance(v, bytes) else v)

    @property
    def freq_hz(self) -> np.ndarray:
        return self.f["freq_hz"][()]

    # ------------------------------------------------------------------ records
    def records(self) -> dict[str, np.ndarray]:
        """All committed stepped-sine records (acquisition order)."""
        n = self.n_done
        return {name: ds[:n] for name, ds in self.acq["records"].items()}

    def append_record(self, row: dict) -> None:
        """Write one stepped-sine record row (not yet committed)."""
        rec = self.acq["records"]
        n = self.n_done
        for name, (dt, per_ch) in SINE_FIELDS.items():
            if name not in rec:  # a file from before the field existed: unknown so far (NaN)
                nch = rec["X"].shape[1]
                shape = (n, nch) if per_ch else (n,)
                rec.create_dataset(name, shape=shape, maxshape=(None,) + shape[1:],
                                   chunks=(RECORD_CHUNK_ROWS,) + shape[1:], dtype=dt, fillvalue=np.nan)
            ds = rec[name]
            ds.resize(n + 1, axis=0)
            v = row.get(name, np.nan if name == "X_transient" else 0)  # NaN: not known
            if name == "reason":
                v = str(v or "").encode("utf-8")[:ds.dtype.itemsize]  # files from before hold 160
            ds[n] = v

    def write_line(self, k: int, H: np.ndarray, H_var: np.ndarray, coherence: np.ndarray, valid: np.ndarray,
                   H_reaction: np.ndarray | None, H_reaction_var: np.ndarray | None = None) -> None:
        """Contract rows of grid line ``k`` (all its sub-lines are measured)."""
        self._write(k, H, H_var, coherence, valid, H_reaction, H_reaction_var)
        self.acq["line_done"][k] = True

    def write_view(self, H, H_var, coherence, valid, H_reaction=None, H_reaction_var=None,
                   n_avg: int | None = None) -> None:
        """The whole contract view at once (random runs: every average refines every bin),
        with the contract's ``n_avg`` of what it holds, so that a stopped run's file says it."""
        self._write(Ellipsis, H, H_var, coherence, valid, H_reaction, H_reaction_var)
        self.acq["line_done"][...] = True
        if n_avg is None:
            return
        if "n_avg" in self.f.attrs:
            self.f.attrs.modify("n_avg", np.int64(n_avg))  # its value in place: same type and size
        else:  # a new attribute grows the root's header: structure (:meth:`_edit_in_copy`)
            self._edit_in_copy(lambda f: f.attrs.create("n_avg", np.int64(n_avg)))

    def _write(self, k, H, H_var, coherence, valid, H_reaction, H_reaction_var) -> None:
        # A variance of 0 where a value is unknown: readers treat it as "no estimate".
        f = self.f
        f["H"][k] = np.where(valid, H, np.nan + 0j)
        f["H_var"][k] = np.where(np.isfinite(H_var), H_var, 0.0)
        f["coherence"][k] = np.clip(np.nan_to_num(coherence), 0.0, 1.0)
        if H_reaction is not None and "H_reaction" in f:
            f["H_reaction"][k] = np.nan_to_num(H_reaction)
            if H_reaction_var is not None and "H_reaction_var" in f:
                f["H_reaction_var"][k] = np.where(np.isfinite(H_reaction_var), H_reaction_var, 0.0)
        f["valid"][k] = valid

    def write_arrays(self, group: str, arrays: dict[str, np.ndarray],
                     descriptions: dict[str, str] | None = None) -> None:
        """Fixed-shape arrays under ``/acq/<group>``: overwritten in place where they exist with
        their shape, else created in an edited copy (:meth:`_edit_in_copy`), with the
        ``description`` attribute given for each in ``descriptions``."""
        g = self.acq.get(group)
        if isinstance(g, h5py.Group) and all(name in g and g[name].shape == np.shape(a) for name, a in arrays.items()):
            for name, a in arrays.items():
                g[name][...] = a
            return

        def edit(f: h5py.File) -> None:
            h = f["acq"].require_group(group)
            for name, a in arrays.items():
                if name in h:
                    del h[name]
                h.create_dataset(name, data=a)
                if descriptions and name in descriptions:
                    h[name].attrs["description"] = descriptions[name]

        self._edit_in_copy(edit)

    def read_arrays(self, group: str) -> dict[str, np.ndarray]:
        if group not in self.acq:
            return {}
        return {name: ds[()] for name, ds in self.acq[group].items()}

    def append_raw(self, data: np.ndarray) -> None:
        """Raw time samples (n_ch, n) of the line just measured (float32, not compressed: see
        the module's docstring) into ``/acq/raw`` (:mod:`daq.raw_store`), which :meth:`create`
        made (``raw_time``); what it lacks is added in an edited copy."""
        nch, n = data.shape
        if "raw" not in self.acq:  # a session resumed with raw_time, or a file from before
            self._edit_in_copy(lambda f: create_raw(f["acq"], nch, n))
        missing = segments_missing(self.acq["raw"], n)
        if missing:
            self._edit_in_copy(lambda f: add_segments(f["acq/raw"], nch, missing))
        append_raw(self.acq["raw"], self.n_done, data)

    def commit(self, n_done: int) -> None:
        """Mark everything written so far as complete and push it to disk: what is counted
        first, then the counter (see the module's docstring)."""
        self.f.flush()
        self.acq["n_done"][0] = n_done
        self.f.flush()

    def set_state(self, state: str) -> None:
        self.acq.attrs["state"] = state
        self.f.flush()

    def set_meta(self, meta: dict) -> None:
        """Replace ``/acq/meta_json`` (in an edited copy, :meth:`_edit_in_copy`)."""

        def edit(f: h5py.File) -> None:
            del f["acq/meta_json"]
            f["acq"].create_dataset("meta_json", data=json.dumps(meta), dtype=_STR)

        self._edit_in_copy(edit)

    # ------------------------------------------------------------------ finish
    # (finalize and _edit_in_copy: daq.run_file_replace.ReplacedByCopy)
    def close(self) -> None:
        if self.f.id.valid:
            self.f.flush()
            self.f.close()
