"""``identify`` names a load cell that disagrees with the accelerances (QA F1).

The payload's 16-DOF substructure on its stand (shakers at 11+Z, 16+Z; load cells at 4+Z, 8+Z,
18+Z), 20-1500 Hz, with the stated variance of its relative noise. A flipped sign, a wrong
label, a reaction not measured and a 10 % calibration error each left step 1's roots exact
and M wrong, with only a misfit warning that advised a wider band.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
import pytest

from ssid.identify import identify_mck


@lru_cache(maxsize=1)
def _exact():
    from ssid.models import frf_on_test_stand
    from ssid.models.payload import Z_DOFS, modal_damping, payload_simulator
    from ssid.tam import guyan_reduce

    p = payload_simulator()
    sub = guyan_reduce(p.M, p.K, p.index(Z_DOFS))
    M, K = (sub.M + sub.M.T) / 2, (sub.K + sub.K.T) / 2
    return frf_on_test_stand(M, modal_damping(M, K, 0.02), K, list(Z_DOFS), ["11+Z", "16+Z"],
                             ["4+Z", "8+Z", "18+Z"], np.geomspace(20.0, 1500.0, 170))


def _noisy(rel: float, seed: int):
    """Complex relative noise of std ``rel`` on every value, and its variance stated."""
    frf = _exact()
    rng = np.random.default_rng(seed)

    def noise(X):
        return X * (1 + rel / np.sqrt(2) * (rng.standard_normal(X.shape) + 1j * rng.standard_normal(X.shape)))

    return dataclasses.replace(frf, H=noise(frf.H), H_reaction=noise(frf.H_reaction),
                               H_var=rel**2 * np.abs(frf.H) ** 2, H_reaction_var=rel**2 * np.abs(frf.H_reaction) ** 2)


def _altered(frf, kind: str):
    R, V, labels = frf.H_reaction.copy(), frf.H_reaction_var.copy(), list(frf.reactions)
    if kind == "flip":  # 8+Z mounted or wired reversed
        R[:, 1] *= -1
    elif kind == "scale":  # 4+Z's sensitivity 10 % off
        R[:, 0] *= 1.1
        V[:, 0] *= 1.21
    elif kind == "relabel":  # 18+Z's reaction recorded as 17+Z
        labels[2] = "17+Z"
    elif kind == "drop":  # 8+Z's post is there, its reaction not measured
        R, V, labels = R[:, [0, 2]], V[:, [0, 2]], [labels[0], labels[2]]
    return dataclasses.replace(frf, H_reaction=R, H_reaction_var=V, reactions=labels)


def _load_cell_warnings(result) -> list[str]:
    return [w for w in result.warnings if w.startswith("load cell(s) disagree")]


@pytest.mark.parametrize("kind, rel, cell, factor", [
    ("flip", 1e-4, "8+Z", -1.0),
    ("relabel", 1e-4, "17+Z", None),
    ("drop", 1e-4, "18+Z", None),  # the cell left to carry 8+Z's post reads ~0
    ("scale", 1e-5, "4+Z", 1.1),  # at 1e-4 a 10 % error lies within the ratio's noise (1.6 sigma)
])
def test_a_wrong_load_cell_is_named(kind, rel, cell, factor):
    r = identify_mck(_altered(_noisy(rel, 1), kind))
    said = _load_cell_warnings(r)
    assert len(said) == 1 and said[0].startswith(f"load cell(s) disagree with the accelerances: {cell} reads")
    assert "sign" in said[0] and "calibration" in said[0] and "label" in said[0] and "not measured" in said[0]
    check = r.info["load_cells"]
    assert check["suspect"] == [cell]
    if factor is not None:
        c = check["cells"][cell]
        assert abs(c["factor"] - factor) < 3 * c["sigma"] and abs(c["factor"] - factor) < 0.02
    trial = check.get("correction_trial")
    if factor is not None:
        # Read by its factor the cell explains the misfit (identified again), which is then put
        # to the load cell first, not to the band.
        assert trial["explains"] and trial["misfit_corrected"] < 0.1 * trial["misfit_as_read"], trial
        assert not any("one that reaches the structure's higher modes" in w for w in r.warnings)
        assert any("check the load cells first" in w for w in r.warnings)
    else:
        # A label or a reaction not measured: no one factor corrects it, and the misfit is not
        # said to be explained by the cells (a short band makes cells look wrong too).
        assert trial is None or not trial["explains"], trial
        assert not any("check the load cells first" in w for w in r.warnings)


@pytest.mark.parametrize("rel, seed", [(1e-4, 1), (1e-4, 2), (1e-4, 3), (1e-5, 1)])
def test_clean_load_cells_are_not_suspected(rel, seed):
    r = identify_mck(_noisy(rel, seed))
    assert _load_cell_warnings(r) == []
    cells = r.info["load_cells"]["cells"]
    assert set(cells) == {"4+Z", "8+Z", "18+Z"}
    assert all(abs(c["factor"] - 1) < 3 * c["sigma"] for c in cells.values())


def test_no_load_cell_check_without_reactions():
    frf = dataclasses.replace(_noisy(1e-4, 1), H_reaction=None, H_reaction_var=None, reactions=None)
    assert "load_cells" not in identify_mck(frf).info


def test_the_correction_trial_asks_for_the_damping_the_caller_asked_for(monkeypatch):
    """The trial identified again with the damping matrix the first run wrote (``step1``, as
    on the guide's stand run), which is no option of ``identify_mck``: where a suspect cell
    met a written ``step1`` damping, ``identify`` stopped with "unknown damping option". The
    choice is made ``step1`` here (a wrong cell usually spoils the agreement of step 2's mass
    copies that step 1's damping needs, so a record does not readily give it)."""
    import ssid.identify as ident

    choose = ident.choose_damping

    def written_as_step1(*args):
        C, name, info = choose(*args)
        info["frf_relative_rms_error"]["step1"] = info["frf_relative_rms_error"][name]
        return C, "step1", info

    monkeypatch.setattr(ident, "choose_damping", written_as_step1)
    r = identify_mck(_altered(_noisy(1e-4, 1), "flip"))
    assert r.damping == "step1"
    assert r.info["load_cells"]["correction_trial"]["explains"]
