"""Which modes are at rest, and which share a frequency, decide how ``ssidlab correlate``
compares them.

1. A mode at rest paired by the MAC alone, with any mode: a 0.47 Hz suspension mode in a
   5.2 kHz test band paired with an 800 Hz analysis mode, a model's rigid-body mode with an
   800 Hz test mode.
2. Elastic modes within 1e-6 of each other in frequency were one repeated root, compared as a
   subspace; split by 2e-6 they were compared mode by mode: MAC 0.5 and a fail, for pairs no
   test can tell apart. The bound is now 2e-4, still a cliff, which is tested where it is.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.correlate import modes_at_rest
from ssid.correlate_groups import REPEATED_FREQ_RTOL
from ssid.correlate_models import correlate_models
from ssid.correlate_pairs import mode_correlation
from ssid.io import Model


def _two_towers(split: float, angle_deg: float) -> Model:
    """Two uncoupled 3-DOF chains (x, y) of one tower, the y chain's masses heavier by the
    factor ``1 / (1 - split)^2`` (its frequencies lower by the fraction ``split``), seen in axes
    turned by ``angle_deg``: each root a pair split by ``split``, its modes along the turned axes."""
    m = np.eye(3)
    k = 1e3 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    M = sla.block_diag(m, m / (1 - split) ** 2)
    K = sla.block_diag(k, k)
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    T = np.kron(np.array([[c, -s], [s, c]]), np.eye(3))  # x' = T x: the same structure, turned
    M, K = T @ M @ T.T, T @ K @ T.T
    return Model((M + M.T) / 2, (K + K.T) / 2, None, ["1+X", "2+X", "3+X", "1+Y", "2+Y", "3+Y"])


@pytest.mark.parametrize("split", [2e-6, 1e-5, 1e-4])
def test_a_nearly_repeated_root_no_test_resolves_is_compared_as_a_subspace(split):
    """The test tower's pairs lie along x and y, the model's along axes turned by 45 degrees;
    both split alike. Split by 0.5e-6 the pairs were repeated roots (MAC 1, pass), split by
    2e-6 they were compared mode by mode (MAC 0.5, fail)."""
    s = correlate_models(_two_towers(split, 0.0), _two_towers(split, 45.0)).summary
    f = np.asarray(s["test_natural_freq_hz"])
    assert f[1] / f[0] - 1 == pytest.approx(split, rel=1e-3)
    assert [(p["test_mode"], p["analysis_mode"]) for p in s["paired_modes"]] == [(i, i) for i in range(1, 7)]
    assert min(p["mac"] for p in s["paired_modes"]) > 0.999
    assert s["cross_orthogonality"]["pass"]
    # The per-mode MACs before the rotation are reported with each group: 0.5.
    assert [g["test_modes"] for g in s["subspaces"]] == [[1, 2], [3, 4], [5, 6]]
    assert np.allclose(np.asarray(s["subspaces"][0]["mac_before_rotation"]), 0.5, atol=1e-3)


def test_the_verdict_changes_at_the_documented_split():
    """Above ``REPEATED_FREQ_RTOL`` (2e-4) the modes are distinct and compared mode by mode:
    split by 2e-3, the test's x and y modes against the model's turned by 45 degrees have MAC
    0.5 and fail, as they do for a real structure whose modes a test resolves. The bound is a
    cliff, as documented: split by 1.99e-4 the same towers pass, by 2.01e-4 they fail."""
    assert REPEATED_FREQ_RTOL == 2e-4
    s = correlate_models(_two_towers(2e-3, 0.0), _two_towers(2e-3, 45.0)).summary
    assert not s["subspaces"]
    assert not s["cross_orthogonality"]["pass"]
    assert max(p["mac"] for p in s["paired_modes"]) < 0.51
    s = correlate_models(_two_towers(2.01e-4, 0.0), _two_towers(2.01e-4, 45.0)).summary
    assert not s["subspaces"] and not s["cross_orthogonality"]["pass"]
    s = correlate_models(_two_towers(1.99e-4, 0.0), _two_towers(1.99e-4, 45.0)).summary
    assert s["cross_orthogonality"]["pass"] and len(s["subspaces"]) == 3


def test_a_suspension_mode_at_rest_pairs_with_an_elastic_mode_only_within_the_frequency_ratio():
    """A 0.47 Hz suspension mode beside a first elastic mode at 150 Hz in a 5.2 kHz band is at
    rest to the pairing's bound (8e-9 of the top omega^2), and was paired by the MAC alone with
    a constrained model's 800 Hz mode whose shape it resembles at the sensors: a factor 1700
    apart, no pair."""
    f_test = np.array([0.47, 150.0, 2000.0, 5200.0])
    assert modes_at_rest(f_test).tolist() == [True, False, False, False]
    phi = np.linalg.qr(np.random.default_rng(3).normal(size=(4, 4)))[0]
    f_an = np.array([800.0, 150.0, 2000.0, 5200.0])
    s, _, pairs = mode_correlation(phi, f_test, phi, f_an, np.eye(4))
    assert [(p.test, p.analysis) for p in pairs] == [(1, 1), (2, 2), (3, 3)]
    [left] = s["not_paired"]
    assert left["test_mode"] == 1 and left["analysis_mode"] == 1
    assert left["reason"].startswith("frequencies a factor 1.7e+03 apart")
    assert "the test mode is at rest, the analysis mode is not" in left["reason"]


def test_a_rigid_body_mode_of_the_model_pairs_by_the_mac_alone_only_with_a_mode_at_rest():
    """The reverse: a model's rigid-body mode (1e-4 Hz beside 5.2 kHz) against a test mode at
    800 Hz whose shape it resembles at the sensors; and a test suspension mode at rest
    (0.47 Hz), which pairs with it by the MAC alone."""
    phi = np.linalg.qr(np.random.default_rng(3).normal(size=(4, 4)))[0]
    f_an = np.array([1e-4, 150.0, 2000.0, 5200.0])
    s, _, pairs = mode_correlation(phi, np.array([800.0, 150.0, 2000.0, 5200.0]), phi, f_an, np.eye(4))
    assert [(p.test, p.analysis) for p in pairs] == [(1, 1), (2, 2), (3, 3)]
    assert "the analysis mode is at rest, the test mode is not" in s["not_paired"][0]["reason"]
    s, _, pairs = mode_correlation(phi, np.array([0.47, 150.0, 2000.0, 5200.0]), phi, f_an, np.eye(4))
    assert [(p.test, p.analysis) for p in pairs] == [(i, i) for i in range(4)]
