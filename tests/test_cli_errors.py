"""The ``ssidlab`` command line: one-line errors with exit status 2, never a traceback.

Bad-input cases run the real command in a subprocess (``python -m ssidlab``). The plumbing of
``identify`` around the solver (files written, table, warnings, error classes) is checked
in-process with a stand-in ``ssid.identify`` module, so it does not depend on the solver.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types
from pathlib import Path

import h5py
import numpy as np
import pytest

import ssidlab
from ssid.errors import IdentificationError
from ssid.io import read_model, write_frf
from ssidlab.cli import main

REPO_ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
    env.pop("SSIDLAB_DEBUG", None)
    return subprocess.run(
        [sys.executable, "-m", "ssidlab", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def assert_one_line_error(proc: subprocess.CompletedProcess, prefix: str, fragment: str = ""):
    lines = proc.stderr.splitlines()
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout
    assert len(lines) == 1 and lines[0].strip(), proc.stderr
    assert lines[0].startswith(prefix), lines[0]
    assert fragment in lines[0], lines[0]


@pytest.fixture
def good_file(tmp_path, frf) -> Path:
    path = tmp_path / "frf.h5"
    write_frf(path, frf)
    return path


def corrupted(path: Path, corrupt) -> Path:
    with h5py.File(path, "r+") as f:
        corrupt(f)
    return path


def _set_labels(name, labels):
    def corrupt(f):
        del f[name]
        f.create_dataset(name, data=np.array(labels, dtype=object), dtype=h5py.string_dtype())

    return corrupt


def _nan_in_h(f):
    H = f["H"][()]
    H[4, 1, 0] = np.nan
    f["H"][...] = H


def _repeat_a_line(f):
    freq = f["freq_hz"][()]
    freq[20] = freq[19]
    f["freq_hz"][...] = freq


BAD_FILES = [
    ("missing-H", lambda f: f.__delitem__("H"), "missing dataset /H"),
    ("nan-in-H", _nan_in_h, "H holds NaN or Inf"),
    ("input-not-output", _set_labels("inputs", ["1+Z", "8+Z"]), "'8+Z' is not among outputs"),
    ("freq-not-increasing", _repeat_a_line, "strictly increasing"),
]


@pytest.mark.parametrize(
    "corrupt, fragment", [c[1:] for c in BAD_FILES], ids=[c[0] for c in BAD_FILES]
)
def test_identify_rejects_malformed_frf_file(tmp_path, good_file, corrupt, fragment):
    corrupted(good_file, corrupt)
    proc = run_cli(
        "identify", str(good_file), "--out", "m.h5", "--json", "r.json", cwd=tmp_path
    )
    assert_one_line_error(proc, "ssidlab identify: error: ", fragment)
    assert not (tmp_path / "m.h5").exists() and not (tmp_path / "r.json").exists()


def test_identify_rejects_text_file(tmp_path):
    (tmp_path / "frf.h5").write_text("this is not HDF5\n")
    proc = run_cli("identify", "frf.h5", "--out", "m.h5", "--json", "r.json", cwd=tmp_path)
    assert_one_line_error(proc, "ssidlab identify: error: frf.h5: ", "not an HDF5 file")


def test_identify_rejects_missing_file(tmp_path):
    proc = run_cli("identify", "gone.h5", "--out", "m.h5", "--json", "r.json", cwd=tmp_path)
    assert_one_line_error(proc, "ssidlab identify: error: gone.h5: ", "no such file")


OUTS = ["--out", "m.h5", "--json", "r.json"]
BAD_ARGUMENTS = [
    ("unknown-option", [*OUTS, "--bogus"], "unrecognized arguments: --bogus"),
    ("missing-out", ["--json", "r.json"], "the following arguments are required: --out"),
    ("fmin-equals-fmax", [*OUTS, "--fmin", "30", "--fmax", "30"], "--fmin (30 Hz) must be below"),
    ("fmin-above-fmax", [*OUTS, "--fmin", "40", "--fmax", "10"], "must be below --fmax (10 Hz)"),
    ("fmin-not-number", [*OUTS, "--fmin", "abc"], "argument --fmin: not a number"),
    ("fmax-infinite", [*OUTS, "--fmax", "inf"], "argument --fmax: must be a finite frequency"),
    ("unknown-solver", [*OUTS, "--solver", "magic"], "argument --solver: invalid choice"),
    ("band-empty", [*OUTS, "--fmin", "500"], "no frequency lines between --fmin and --fmax"),
    ("out-dir-missing", ["--out", "no/dir/m.h5", "--json", "r.json"], "does not exist"),
    ("out-is-input", ["--out", "frf.h5", "--json", "r.json"], "would overwrite the input file"),
    ("out-twice", ["--out", "m.h5", "--json", "m.h5"], "given for two different outputs"),
]
if os.path.isdir("/proc/self"):  # a directory that takes no file, even for root (Linux)
    BAD_ARGUMENTS.append(("json-dir-takes-no-file", ["--out", "m.h5", "--json", "/proc/r.json"],
                          "/proc/r.json: cannot write in directory '/proc'"))


@pytest.mark.parametrize(
    "args, fragment", [c[1:] for c in BAD_ARGUMENTS], ids=[c[0] for c in BAD_ARGUMENTS]
)
def test_identify_rejects_bad_arguments(tmp_path, good_file, args, fragment):
    proc = run_cli("identify", good_file.name, *args, cwd=tmp_path)
    assert_one_line_error(proc, "ssidlab identify: error: ", fragment)


@pytest.mark.parametrize(
    "args, fragment",
    [([], "required: COMMAND"), (["frobnicate"], "invalid choice: 'frobnicate'")],
    ids=["no-command", "unknown-command"],
)
def test_top_level_usage_errors(tmp_path, args, fragment):
    proc = run_cli(*args, cwd=tmp_path)
    assert_one_line_error(proc, "ssidlab: error: ", fragment)


def test_an_unknown_option_is_named_before_a_missing_required_one(tmp_path):
    """``ssidlab demo --bogus`` said "required: --out" (a contract check): the mistake made
    is the unknown option."""
    proc = run_cli("demo", "--bogus", cwd=tmp_path)
    assert_one_line_error(proc, "ssidlab demo: error: ", "unrecognized arguments: --bogus")
    proc = run_cli("demo", cwd=tmp_path)
    assert_one_line_error(proc, "ssidlab demo: error: ", "required: --out")


def test_version(tmp_path):
    proc = run_cli("--version", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"ssidlab {ssidlab.__version__}"
    assert proc.stderr == ""


def test_help_exits_0(tmp_path):
    proc = run_cli("identify", "--help", cwd=tmp_path)
    assert proc.returncode == 0 and "--solver" in proc.stdout


# ----------------------------------------------------------------------------------------------
# identify around the solver, with a stand-in ssid.identify
# ----------------------------------------------------------------------------------------------


class FakeResult:
    def __init__(self, model, dofs, warnings):
        self.M, self.C, self.K = model.M, model.C, model.K
        self.dofs = dofs
        self.warnings = warnings
        # What the model file's provenance takes from an SSIDResult.
        self.band_hz, self.solver, self.damping = (5.0, 25.0), "ml", "identified"

    def to_model(self):
        from ssid.io import Model

        return Model(M=self.M, K=self.K, C=self.C, dofs=list(self.dofs))

    def to_json_dict(self) -> dict:
        return {
            "natural_freq_hz": np.array([5.1, 14.2, 21.9]),
            "damping_ratio": [np.float64(0.012), 0.02, None],
            "undamped_freq_hz": [5.0, float("nan"), 22.0],  # NaN: M not definite
            "dofs": self.dofs,
        }


@pytest.fixture
def fake_identify(monkeypatch, model):
    """Install a stand-in ``ssid.identify``; ``calls`` records the keyword arguments."""
    calls: list[dict] = []
    behaviour = {"raise": None, "dofs": None, "warnings": ["few lines near 60 Hz"]}

    def identify_mck(frf, **kwargs):
        calls.append(kwargs)
        if behaviour["raise"] is not None:
            raise behaviour["raise"]
        dofs = behaviour["dofs"] or list(frf.outputs)
        return FakeResult(model, dofs, behaviour["warnings"])

    module = types.ModuleType("ssid.identify")
    module.identify_mck = identify_mck
    monkeypatch.setitem(sys.modules, "ssid.identify", module)
    monkeypatch.delenv("SSIDLAB_DEBUG", raising=False)
    return types.SimpleNamespace(calls=calls, behaviour=behaviour)


def test_identify_writes_model_json_and_table(tmp_path, good_file, fake_identify, model, capsys):
    out, js = tmp_path / "m.h5", tmp_path / "r.json"
    rc = main(["identify", str(good_file), "--out", str(out), "--json", str(js),
               "--solver", "tls", "--fmin", "3", "--fmax", "50", "--damping", "modal"])
    captured = capsys.readouterr()

    assert rc == 0, captured.err
    assert fake_identify.calls == [
        {"solver": "tls", "f_min_hz": 3.0, "f_max_hz": 50.0, "damping": "modal"}
    ]
    back = read_model(out)
    np.testing.assert_array_equal(back.K, model.K)
    assert back.dofs == ["1+Z", "2+Z", "3+Z"]
    result = json.loads(js.read_text())
    assert result["natural_freq_hz"] == [5.1, 14.2, 21.9]
    assert result["dofs"] == ["1+Z", "2+Z", "3+Z"]
    assert captured.err == "warning: few lines near 60 Hz\n"
    table = captured.out.splitlines()
    assert len(table) == 4 and "f_n [Hz]" in table[0]
    assert table[1].split() == ["1", "5.1000", "1.200", "5.0000"]
    assert table[2].split() == ["2", "14.2000", "2.000", "-"]
    assert table[3].split() == ["3", "21.9000", "-", "22.0000"]


def test_an_output_that_is_a_pipe_is_refused_not_replaced(tmp_path, good_file, fake_identify, capsys):
    """Files are written under a temporary name and renamed onto the name given: onto a
    device or a pipe that replaced it with a regular file (as root, ``--out /dev/null``
    replaced the system's /dev/null). A named pipe stands in for the device here. It is said
    before the identification (QA: --json /dev/full was said only after it)."""
    for name in ("m.h5", "r.json"):
        out = tmp_path / name
        os.mkfifo(out)
        other = {"m.h5": tmp_path / "ok.json", "r.json": tmp_path / "ok.h5"}[name]
        h5, js = (out, other) if name == "m.h5" else (other, out)
        rc = main(["identify", str(good_file), "--out", str(h5), "--json", str(js)])
        err = capsys.readouterr().err
        assert rc == 2 and err.startswith(f"ssidlab identify: error: {out}: cannot write (it exists and is not a "
                                          "regular file"), err
        assert out.is_fifo() and not other.exists()
        out.unlink()
    assert fake_identify.calls == []


def test_identify_defaults_and_quiet(tmp_path, good_file, fake_identify, capsys):
    rc = main(["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
               "--json", str(tmp_path / "r.json"), "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0
    assert fake_identify.calls == [
        {"solver": "ml", "f_min_hz": None, "f_max_hz": None, "damping": "auto"}
    ]
    assert captured.out == ""


def test_identification_error_is_bad_input(tmp_path, good_file, fake_identify, capsys):
    fake_identify.behaviour["raise"] = IdentificationError("too few valid lines for 18 unknowns")
    rc = main(["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
               "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 2
    # The file it was said of (a contract check's one-line FRF had the reason only).
    assert err == f"ssidlab identify: error: {good_file}: too few valid lines for 18 unknowns\n"


def test_unexpected_exception_is_internal_error(tmp_path, good_file, fake_identify, capsys):
    fake_identify.behaviour["raise"] = ZeroDivisionError("division by zero")
    args = ["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
            "--json", str(tmp_path / "r.json")]
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 1
    assert err == "ssidlab identify: internal error: ZeroDivisionError: division by zero\n"


def test_sigterm_ends_a_command_as_ctrl_c_does(tmp_path, good_file):
    """A scheduler's or a controlling program's SIGTERM during the computation: the command
    died with 143 and said nothing, where docs/formats.md promises 130 and "interrupted"."""
    code = ("import os, signal, sys, time, types\n"
            "def identify_mck(frf, **kw):\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "    time.sleep(60)\n"
            "sys.modules['ssid.identify'] = types.SimpleNamespace(identify_mck=identify_mck)\n"
            "from ssidlab.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    p = subprocess.run([sys.executable, "-c", code, "identify", str(good_file), "--out", str(tmp_path / "m.h5"),
                        "--json", str(tmp_path / "r.json")], capture_output=True, text=True, env=env, timeout=60)
    assert p.returncode == 130 and p.stderr == "ssidlab identify: interrupted\n", (p.returncode, p.stderr)
    assert not (tmp_path / "m.h5").exists()


def test_debug_env_reraises(tmp_path, good_file, fake_identify, monkeypatch):
    fake_identify.behaviour["raise"] = ZeroDivisionError("division by zero")
    monkeypatch.setenv("SSIDLAB_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
              "--json", str(tmp_path / "r.json")])


def test_result_over_wrong_dofs_is_internal_error(tmp_path, good_file, fake_identify, capsys):
    fake_identify.behaviour["dofs"] = ["3+Z", "2+Z", "1+Z"]
    rc = main(["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
               "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1 and "differ from the FRF outputs" in err


def test_python_warnings_are_one_line(tmp_path, good_file, fake_identify, capsys):
    def identify_mck(frf, **kwargs):
        np.log(np.zeros(1))  # numpy RuntimeWarning: divide by zero
        return FakeResult(types.SimpleNamespace(M=np.eye(3), C=None, K=np.eye(3)),
                          list(frf.outputs), [])

    sys.modules["ssid.identify"].identify_mck = identify_mck
    rc = main(["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
               "--json", str(tmp_path / "r.json"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 0
    assert err.startswith("warning: divide by zero") and err.count("\n") == 1


def test_library_warnings_are_dropped_when_the_command_fails(
    tmp_path, good_file, fake_identify, capsys
):
    def identify_mck(frf, **kwargs):
        np.mean(np.zeros(0))  # numpy RuntimeWarning: Mean of empty slice
        raise IdentificationError("no equation-error start could be computed")

    sys.modules["ssid.identify"].identify_mck = identify_mck
    rc = main(["identify", str(good_file), "--out", str(tmp_path / "m.h5"),
               "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err == f"ssidlab identify: error: {good_file}: no equation-error start could be computed\n"


def test_an_ignored_sigint_is_taken_from_the_first_line():
    """A process started with SIGINT ignored (in the background by a script or a CI runner)
    lost an interrupt in the command's first second, before ``ssidlab acquire`` put its run
    handler in place, and the run then went on to drive. ``main`` makes SIGINT raise
    KeyboardInterrupt first thing, for its own run; a handler of a program embedding it is
    left alone."""
    import signal

    from ssidlab.cli import _interruptible

    before = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with _interruptible():
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # as the embedding program had it

        def own(signum, frame):
            pass

        signal.signal(signal.SIGINT, own)
        with _interruptible():
            assert signal.getsignal(signal.SIGINT) is own
    finally:
        signal.signal(signal.SIGINT, before)


# ----------------------------------------------------------------------------------------------
# a disk that takes no more (a file-size limit stands in for a full disk)
# ----------------------------------------------------------------------------------------------


def _with_file_size_limit(limit_bytes: int):
    """preexec_fn: writes past ``limit_bytes`` fail with EFBIG (SIGXFSZ ignored), as on a full disk."""
    import resource
    import signal

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return limit


@pytest.mark.skipif(not hasattr(os, "fork"), reason="preexec_fn needs fork")
def test_a_model_file_the_disk_cannot_take_is_one_line_and_no_file(tmp_path, good_file):
    """HDF5 reported the failed write while closing the file, where h5py only printed it: a
    half-written model was renamed into place (unreadable), tracebacks were printed, and the
    interpreter crashed at exit (exit 139)."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    env.pop("SSIDLAB_DEBUG", None)
    proc = subprocess.run(
        [sys.executable, "-m", "ssidlab", "identify", str(good_file), "--out", "m.h5", "--json", "r.json",
         "--quiet"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
        preexec_fn=_with_file_size_limit(4096))
    assert_one_line_error(proc, "ssidlab identify: error: m.h5: cannot write (File too large)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frf.h5"]  # no model, no temporary, no JSON


@pytest.mark.skipif(not hasattr(os, "fork"), reason="preexec_fn needs fork")
def test_a_json_summary_the_disk_cannot_take_leaves_the_old_one_whole(tmp_path):
    """The JSON summaries were written straight onto their names: a full disk left a
    truncated, unreadable summary in place of the good one."""
    old = tmp_path / "r.json"
    old.write_text('{"good": true}\n')
    code = ("import sys; from ssidlab.argtypes import write_json\n"
            "try:\n    write_json(sys.argv[1], {'x': list(range(5000))})\n"
            "except OSError as exc:\n    print(exc)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(old)], cwd=tmp_path, capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)), timeout=60,
                          preexec_fn=_with_file_size_limit(4096))
    assert proc.stdout.strip() == f"{old}: cannot write (File too large)", proc.stderr
    assert json.loads(old.read_text()) == {"good": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="preexec_fn needs fork")
def test_a_uff_export_the_disk_cannot_take_is_one_line(tmp_path, good_file):
    """pyuff wraps a failed write in a bare Exception, which came out as an internal error
    ("pyuff could not write dataset 2 (type 58)", exit 1)."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    env.pop("SSIDLAB_DEBUG", None)
    proc = subprocess.run([sys.executable, "-m", "ssidlab", "convert", str(good_file), "x.uff"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=120, preexec_fn=_with_file_size_limit(4096))
    assert_one_line_error(proc, "ssidlab convert: error: x.uff: cannot write (File too large)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frf.h5"]
