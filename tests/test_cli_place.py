"""``ssidlab place`` run as a user runs it (subprocess, real files), on the payload simulator."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys

import numpy as np
import pytest

from ssid.io import Model, write_model
from ssid.models.payload import INTERFACE_DOFS, Z_DOFS, payload_simulator
from ssid.tam import normal_modes


def run(*args):
    return subprocess.run([sys.executable, "-m", "ssidlab", "place", *args], capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def payload(tmp_path_factory):
    p = payload_simulator()
    path = tmp_path_factory.mktemp("place") / "fe.h5"
    write_model(str(path), Model(M=p.M, K=p.K, C=None, dofs=list(p.dofs)))
    return p, path


def test_place_chooses_the_dofs_that_best_observe_the_targets(payload, tmp_path):
    """10 Z accelerometers for the 10 lowest modes, the three interface DOFs required (the
    report's inputs). The choice holds them, and of all 1716 sets of 10 Z DOFs that hold them,
    its Fisher information (Eq. 6.1) has one of the largest determinants: the largest, measured
    (Effective Independence is a greedy search, so the check is the top 1 %). The printed
    auto-MAC is that of the targets at the chosen DOFs."""
    p, fe = payload
    js = tmp_path / "place.json"
    r = run(str(fe), "--sensors", "10", "--targets", "1-10", "--direction", "Z", "--require",
            ",".join(INTERFACE_DOFS), "--json", str(js))
    assert r.returncode == 0, r.stderr
    res = json.loads(js.read_text())
    chosen = res["chosen"]
    assert len(chosen) == 10 and set(INTERFACE_DOFS) <= set(chosen) and set(chosen) <= set(Z_DOFS)
    assert res["targets"]["mode_numbers"] == list(range(1, 11))

    _, phi = normal_modes(p.M, p.K)

    def logdet(sel):
        a = phi[np.ix_(p.index(list(sel)), np.arange(10))]
        return np.linalg.slogdet(a.T @ a)[1]

    others = [d for d in Z_DOFS if d not in INTERFACE_DOFS]
    dets = [logdet(INTERFACE_DOFS + list(c)) for c in itertools.combinations(others, 7)]
    assert len(dets) == 1716
    assert sum(d > logdet(chosen) + 1e-9 for d in dets) <= 17
    assert f"{res['max_offdiag_auto_mac']['value']:.3f}" in r.stdout


def test_place_defaults_translations_and_lowest_modes(payload, tmp_path):
    """Without --targets the lowest N modes are the targets; without --direction or
    --candidates every translational DOF is a candidate (the payload has Z only)."""
    _, fe = payload
    js = tmp_path / "d.json"
    r = run(str(fe), "--sensors", "12", "--json", str(js), "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    res = json.loads(js.read_text())
    assert res["n_candidates"] == len(Z_DOFS) and len(res["chosen"]) == 12
    assert res["targets"]["mode_numbers"] == list(range(1, 13))


@pytest.mark.parametrize("extra, message", [
    (["--sensors", "5", "--targets", "1-10"], "between the number of target modes (10)"),
    (["--sensors", "10", "--require", "9+Z"], "not among the candidate DOFs"),
    (["--sensors", "10", "--candidates", "1+Z,99+Z"], "is not a DOF of"),
    (["--sensors", "10", "--targets", "1,60"], "has 52 modes"),
    (["--sensors", "10", "--direction", "X"], "no DOF labelled"),
    (["--sensors", "0"], "must be at least 1"),
    (["--sensors", "3", "--targets", "1-3", "--require", "1+Z,2+Z,3+Z,4+Z"], "more than --sensors"),
])
def test_place_bad_input_is_one_line_and_status_2(payload, tmp_path, extra, message):
    _, fe = payload
    r = run(str(fe), "--json", str(tmp_path / "bad.json"), *extra)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "bad.json").exists()


def test_place_refuses_a_model_with_massless_dofs(tmp_path):
    """A lumped-mass FE model whose rotations carry no mass has no normal modes as it is:
    one line, status 2, and what to do."""
    M = np.diag([1.0, 0.0, 1.0, 0.0])
    K = np.array([[2.0, 0.5, -1.0, 0.0], [0.5, 1.0, 0.0, 0.1], [-1.0, 0.0, 2.0, 0.5],
                  [0.0, 0.1, 0.5, 1.0]]) * 1e4
    fe = tmp_path / "lumped.h5"
    write_model(str(fe), Model(M=M, K=K, C=None, dofs=["1+Z", "1+RX", "2+Z", "2+RX"]))
    r = run(str(fe), "--sensors", "2", "--json", str(tmp_path / "o.json"))
    assert r.returncode == 2, r.stderr
    assert "M is not positive definite" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_place_refuses_an_unstable_model_but_takes_a_free_one(tmp_path):
    """K with a clearly negative eigenvalue (a sign slip in a model file) gave target modes
    "0-0 Hz" and a placement for them; a free-free chain (a rigid-body mode, omega^2 at
    round-off) is still a model to place sensors on."""
    n = 6
    K = 1e4 * (2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    K[0, 0] = K[-1, -1] = 1e4  # free at both ends: one rigid-body mode
    dofs = [f"{k + 1}+Z" for k in range(n)]
    free, unstable = tmp_path / "free.h5", tmp_path / "unstable.h5"
    write_model(str(free), Model(M=np.eye(n), K=K, C=None, dofs=dofs))
    write_model(str(unstable), Model(M=np.eye(n), K=-K, C=None, dofs=dofs))
    r = run(str(free), "--sensors", "3", "--json", str(tmp_path / "f.json"))
    assert r.returncode == 0, r.stderr
    r = run(str(unstable), "--sensors", "3", "--json", str(tmp_path / "u.json"))
    assert r.returncode == 2 and "K is not positive semi-definite" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "u.json").exists()


def test_place_names_two_different_targets_when_none_look_alike(tmp_path):
    """Three uncoupled oscillators (diagonal M and K): every pair of target shapes has MAC 0
    at the chosen DOFs. The pair named must still be two different modes (it said "modes 1
    and 1")."""
    dofs = ["1+Z", "2+Z", "3+Z"]
    model = tmp_path / "uncoupled.h5"
    write_model(str(model), Model(M=np.diag([1.0, 2.0, 3.0]), K=np.diag([1e4, 5e4, 2e5]), C=None, dofs=dofs))
    r = run(str(model), "--sensors", "2", "--json", str(tmp_path / "u.json"))
    assert r.returncode == 0, r.stderr
    pair = json.loads((tmp_path / "u.json").read_text())["max_offdiag_auto_mac"]
    assert pair["value"] == 0.0 and pair["modes"][0] != pair["modes"][1], pair


def _xz_chains(path):
    """Two uncoupled 4-DOF chains of unit masses, one in X (springs 1e5 N/m) and one in Z
    (3.7e5): modes 1, 3, 4 move in X only (17.5, 50.3, 77.1 Hz), mode 2 in Z (33.6 Hz)."""
    n = 4
    chain = 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    chain[-1, -1] = 1.0
    K = np.zeros((2 * n, 2 * n))
    K[:n, :n], K[n:, n:] = 1e5 * chain, 3.7e5 * chain
    dofs = [f"{i}+X" for i in range(1, n + 1)] + [f"{i}+Z" for i in range(1, n + 1)]
    write_model(str(path), Model(M=np.eye(2 * n), K=K, C=None, dofs=dofs))


def test_place_refuses_targets_the_candidates_cannot_observe(tmp_path):
    """Z candidates for the four lowest modes, three of them X modes: their shapes vanish at
    every candidate, F = Phi^T Phi is singular for any choice, so EfI has no meaning. It chose
    "1+Z..4+Z" and printed "largest auto-MAC 0.000" (zero shapes) and "condition of F: inf",
    exit 0; now one line naming the modes, status 2. Every translation as candidates: fine."""
    fe = tmp_path / "xz.h5"
    _xz_chains(fe)
    js = tmp_path / "xz.json"
    r = run(str(fe), "--sensors", "4", "--direction", "Z", "--json", str(js))
    assert r.returncode == 2, r.stdout
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert "target modes 1 (17.48 Hz), 3 (50.33 Hz), 4 (77.11 Hz) vanish at every candidate DOF" in r.stderr
    assert "singular" in r.stderr and not js.exists()
    r = run(str(fe), "--sensors", "4", "--json", str(js))
    assert r.returncode == 0, r.stderr
    assert json.loads(js.read_text())["fisher_condition"] is not None


def test_effective_independence_refuses_rank_deficient_target_shapes():
    """Two targets with one shape at the candidates (rank 1 of 2): no DOF vanishes, but no
    choice tells them apart; refused with the rank."""
    from ssid.errors import InputError
    from ssid.placement import effective_independence

    phi = np.array([[1.0, 2.0], [2.0, 4.0], [3.0, 6.0], [0.5, 1.0]])
    with pytest.raises(InputError, match="have rank 1"):
        effective_independence(phi, 2)
    phi[3, 1] = 0.0  # the shapes now differ at one DOF: full rank, and that DOF is kept
    assert 3 in effective_independence(phi, 2)
