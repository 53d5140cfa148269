"""``ssidlab identify`` on a test stand says what the model is, and the model file says where it
came from (QA F5, F6)."""

from __future__ import annotations

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from ssid.io import read_model, write_frf
from ssid.models import frf_on_test_stand
from ssid.models.payload import modal_damping


def _chain():
    n = 6
    M = np.diag(np.linspace(1.0, 2.0, n))
    K = np.zeros((n, n))
    for i in range(n - 1):
        K[np.ix_([i, i + 1], [i, i + 1])] += 4e5 * np.array([[1, -1], [-1, 1]])
    K[0, 0] += 1e5
    return M, K, [f"{i + 1}+Z" for i in range(n)]


@pytest.fixture(scope="module")
def stand_file(tmp_path_factory):
    M, K, dofs = _chain()
    frf = frf_on_test_stand(M, modal_damping(M, K, 0.02), K, dofs, ["3+Z", "5+Z"], ["1+Z", "6+Z"],
                            np.geomspace(5.0, 400.0, 120))
    path = tmp_path_factory.mktemp("stand") / "stand.h5"
    write_frf(str(path), frf)
    return path


def _identify(frf, tmp, *extra):
    out, js = tmp / "m.h5", tmp / "r.json"
    p = subprocess.run([sys.executable, "-m", "ssidlab", "identify", str(frf), "--out", str(out), "--json", str(js),
                        *extra], capture_output=True, text=True)
    return p, out, js


def test_help_says_reactions_are_applied():
    p = subprocess.run([sys.executable, "-m", "ssidlab", "identify", "--help"], capture_output=True, text=True)
    text = " ".join(p.stdout.split())
    assert "--reactions {apply,ignore}" in text
    assert "substructure alone" in text and "load cells are checked" in text


def test_the_printout_json_and_file_say_the_reactions_were_applied(stand_file, tmp_path):
    p, out, js = _identify(stand_file, tmp_path)
    assert p.returncode == 0, p.stderr
    assert "reactions applied at 1+Z, 6+Z: M, C, K are the substructure alone" in p.stdout
    summary = json.loads(js.read_text())
    assert summary["reactions"]["applied"] == ["1+Z", "6+Z"] and summary["reactions"]["in_file"] == ["1+Z", "6+Z"]
    # The chain's M is diagonal: M^-1 has no entry between a reaction and an input, so no ratio
    # checks its load cells (and none is suspected on noise-free data).
    assert summary["info"]["load_cells"]["suspect"] == []
    assert summary["info"]["load_cells"]["unchecked"] == ["1+Z", "6+Z"]
    with h5py.File(out) as f:
        assert f.attrs["reactions_applied"] == "1+Z,6+Z" and f.attrs["solver"] == "ml"
        assert f.attrs["source_frf"].endswith("stand.h5") and f.attrs["ssidlab_version"]
        assert list(f.attrs["band_hz"]) == pytest.approx(summary["band_hz"])
        assert {k: f[k].attrs["units"] for k in ("M", "C", "K")} == {"M": "kg", "C": "N s/m", "K": "N/m"}
    model = read_model(out)  # reads as before; the provenance comes back as attrs
    M, _, _ = _chain()
    assert np.allclose(model.M, M, rtol=1e-3, atol=1e-3 * M.max())
    assert model.attrs["reactions_in_file"] == "1+Z,6+Z"


def test_reactions_ignore_leaves_them_out_and_says_so(stand_file, tmp_path):
    p, out, js = _identify(stand_file, tmp_path, "--reactions", "ignore")
    assert p.returncode == 0, p.stderr
    assert "reactions at 1+Z, 6+Z not applied (--reactions ignore)" in p.stdout
    summary = json.loads(js.read_text())
    assert summary["reactions"]["applied"] == [] and "load_cells" not in summary["info"]
    with h5py.File(out) as f:
        assert f.attrs["reactions_applied"] == "" and f.attrs["reactions_in_file"] == "1+Z,6+Z"


def test_reactions_apply_without_reactions_is_refused(stand_file, tmp_path):
    from ssid.io import read_frf

    frf = read_frf(str(stand_file))
    frf.H_reaction, frf.reactions = None, None
    free = tmp_path / "free.h5"
    write_frf(str(free), frf)
    p, _, _ = _identify(free, tmp_path, "--reactions", "apply")
    assert p.returncode == 2 and "--reactions apply needs measured interface reactions" in p.stderr
    p, _, _ = _identify(free, tmp_path)
    assert p.returncode == 0 and "reactions" not in p.stdout
