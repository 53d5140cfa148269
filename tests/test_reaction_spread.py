"""A reaction step 1 cannot separate from the substructure (QA finding F3, soft stand).

Known system: a 5-mass free chain (``ssid.models.chain_model``) bolted at its two ends to a
stand (``ssid.models.frf_on_test_stand``), shakers at 2+Z and 4+Z, 200 log-spaced lines
5-400 Hz, the report's noise model at a tenth of its size (0.2 %, 0.2 degree) with the
variances an analyser states, seed 1. On the default stand (2e6 N/m, stand modes in the band)
M comes out within 0.1 %. On a soft, damped stand (2e3 N/m, 400 N s/m, 5e3 N/m to ground:
the post masses barely move in the band) each reaction is 92 % ``-(k + j w c) x`` on its own
DOF (in norm), M^-1 D_r is not determined (Cramer-Rao spread 14 % of it at the fit; 0.04-0.06 %
on the default stand), and M comes out 29 % off. Noise-free, both identify exactly. ``identify`` must name that cause.
"""

from __future__ import annotations

import numpy as np
import pytest

from ssid.identify import identify_mck
from ssid.models import chain_model, frf_on_test_stand
from ssid.noise import report_noise_frf
from ssid.step1_reaction_spread import REACTION_SPREAD_MAX, stand_impedance_fit

SOFT = dict(stand_k_n_per_m=2e3, stand_c_n_s_per_m=400.0, ground_k_n_per_m=5e3)


def _chain_on_stand(stand: dict, seed: int | None):
    M, C, K, dofs = chain_model([1.0, 1.5, 0.8, 1.2, 1.0], [4e5, 3e5, 5e5, 2e5], np.zeros(5),
                                [8.0, 6.0, 10.0, 5.0], np.zeros(5))
    frf = frf_on_test_stand(M, C, K, dofs, ["2+Z", "4+Z"], ["1+Z", "5+Z"], np.geomspace(5.0, 400.0, 200), **stand)
    if seed is not None:
        frf = report_noise_frf(frf, seed, mag_noise=0.002, phase_noise_deg=0.2, with_variance=True)
    return frf, M


def _undetermined(result) -> list[str]:
    return [w for w in result.warnings if w.startswith("step 1 cannot determine the reaction term")]


def test_soft_damped_stand_is_named():
    frf, M = _chain_on_stand(SOFT, seed=1)
    assert min(f["share"] for f in stand_impedance_fit(frf)) > 0.9
    r = identify_mck(frf)
    said = _undetermined(r)
    assert len(said) == 1, r.warnings
    assert "1+Z, 5+Z" in said[0] and "spring and dashpot on their own DOF" in said[0]
    assert min(r.info["reaction_spread"]["spread"].values()) > REACTION_SPREAD_MAX
    # The failure the warning explains: step 2's model (M 29 % off) misses the data; refitted with
    # the reactions as known loads (ssid.reaction_fit), M is within 0.01 %, and the warning says so.
    fit = r.info["reaction_fit"]
    assert fit["accepted"] and fit["frf_relative_rms_error_start"] > 0.5 and fit["frf_relative_rms_error"] < 2e-3
    assert "M, C, K reproduce them to" in said[0] and "are the model written" in said[0]
    assert r.damping == "output_error" and r.n_rigid_body_modes == 0
    assert np.linalg.norm(r.M - M) / np.linalg.norm(M) < 0.01
    # The misfit's advice agrees with it: a wider band does not help (it said "measure a wider band").
    misfit = [w for w in r.warnings if w.startswith("the written M, C, K reproduce")]
    assert all("a wider band does not help" in w and "measure a wider band" not in w for w in misfit), misfit
    # An undetermined reaction column says nothing of its load cell: not checked (the QA's soft
    # stand named all three cells, none of them wrong).
    assert "load_cells" not in r.info and not any(w.startswith("load cell(s)") for w in r.warnings)


@pytest.mark.parametrize("stand, seed", [({}, 1), ({}, None), (SOFT, None)])
def test_determined_reactions_are_not_flagged(stand, seed):
    frf, M = _chain_on_stand(stand, seed)
    r = identify_mck(frf)
    assert not _undetermined(r), r.warnings
    assert np.linalg.norm(r.M - M) / np.linalg.norm(M) < 2e-3
