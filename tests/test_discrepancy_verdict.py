"""Warnings of the discrepancy verdict (``ssid.discrepancy.verdict``) on the updated model."""

from __future__ import annotations

import numpy as np
import pytest

from ssid.discrepancy import find_discrepancy
from ssid.discrepancy.effects import Effect, apply_effect
from ssid.frf import accelerance_from_model
from ssid.io import Model
from ssid.models.lumped import chain_model


@pytest.mark.parametrize("k_n_per_m, unstable", [(-1.3e5, True), (-5e4, False)])
def test_an_effect_that_makes_the_model_unstable_is_warned_of(k_n_per_m, unstable):
    """A four-mass chain held by 1e5 N/m at DOF 1; a grounded spring of -1.3e5 N/m there
    leaves K indefinite (a mode with omega^2 < 0). The workflow named it and wrote the
    updated model with no word of it (a QA session); -5e4 N/m leaves the chain stable. Data:
    the changed chain's FRFs at every DOF, input at 2+Z, 5-250 Hz, 300 lines, noise-free."""
    M, C, K, dofs = chain_model(np.array([1.0, 1.5, 1.2, 0.8]), np.array([1e5, 1.2e5, 0.9e5]),
                                np.array([1e5, 0, 0, 0]), np.full(3, 5.0), np.zeros(4))
    effect = Effect("grounded_spring", ("1+Z",), {"stiffness_n_per_m": k_n_per_m})
    M2, C2, K2, d2 = apply_effect(M, C, K, dofs, effect)
    frf = accelerance_from_model(M2, C2, K2, d2, np.geomspace(5, 250, 300), dofs, ["2+Z"])
    res = find_discrepancy(Model(M=M, C=C, K=K, dofs=dofs), frf)
    assert (res.effect.name, res.dofs) == ("grounded_spring", ["1+Z"])
    assert res.parameters["stiffness_n_per_m"] == pytest.approx(k_n_per_m, rel=1e-3)
    warned = [w for w in res.info["warnings"] if "not a stable structure" in w]
    assert len(warned) == int(unstable)
