"""Free-free (unsupported) structures: rigid-body modes in SSID step 2 (``ssid.rigid_body``).

Each case synthesises exact accelerances of a system with known M, C, K and identifies it.
Tolerances: noise-free, M, C, K within 1e-7 relative (measured 1.5e-10 and 1.0e-10 for the
chain: step 1's maximum-likelihood refinement stops near 1e-8 on C^, and the rigid-body
assembly adds only rounding; a grounded structure's tests allow 1e-5). Under the report's
noise (seed 1), M within 1 % and K within 2 % (measured 0.10-0.35 % and 0.15-1.2 %), every
elastic frequency within 1 % (the grounded tests' tolerance).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.frf import accelerance_from_model
from ssid.identify import identify_mck, identify_step1
from ssid.models.beams import assemble_grillage, box_section
from ssid.models.lumped import chain_model
from ssid.models.payload import modal_damping
from ssid.noise import report_noise_frf
from ssid.rigid_body import rigid_body_clusters, with_rigid_body_modes
from ssid.step2 import assemble_mck, fit_scale_factors, state_space_modes

FREQ_HZ = np.linspace(1.0, 400.0, 400)
ELASTIC_HZ = np.array([38.5203, 71.1763, 92.9963])  # the free chain's damped roots


def rel(A, B):
    return np.linalg.norm(A - B) / np.linalg.norm(B)


def free_chain(k_ground=0.0):
    """4 unit masses, springs 1e5 N/m and dampers 5 N s/m between them; ``k_ground`` N/m to
    ground at both ends (0: free-free, one rigid-body mode)."""
    n = 4
    return chain_model(np.ones(n), np.full(n - 1, 1e5), np.array([k_ground, 0, 0, k_ground]),
                       np.full(n - 1, 5.0), np.zeros(n))


def not_physical(r):
    return [w for w in r.warnings if "not physical" in w or "negative eigenvalues" in w or "real (non" in w]


def test_defective_root_is_what_loses_the_mass():
    """The cause: with step 1's matrices exact, the double root at 0 splits on rounding alone
    and Eq. 3.26 through the eigenvectors loses M entirely; the rigid-body block keeps it."""
    M, C, K, d = free_chain()
    frf = accelerance_from_model(M, C, K, d, FREQ_HZ, d, [d[0]])
    _, data, _ = identify_step1(frf, solver="ls")
    C_hat, K_hat = np.linalg.solve(M, C), np.linalg.solve(M, K)
    modes = state_space_modes(C_hat, K_hat)
    Mx = assemble_mck(modes, fit_scale_factors(data, modes).u)[0]
    assert rel(Mx, M) > 0.1
    cluster = rigid_body_clusters(modes, float(data.omega.min()))[0]
    rigid = with_rigid_body_modes(modes, C_hat, K_hat, cluster)
    fit = fit_scale_factors(data, rigid)
    Mr, Cr, Kr, _ = assemble_mck(rigid, fit.u, fit.rigid_inv_mass)
    assert rel(Mr, M) < 1e-10 and rel(Cr, C) < 1e-10 and rel(Kr, K) < 1e-10
    # Phi0 = (1, 1, 1, 1) / 2 (unit norm): Phi0^T M Phi0 = 1 kg, the inverse of the mass line.
    assert fit.rigid_inv_mass[0, 0] == pytest.approx(1.0, rel=1e-10)


@pytest.mark.parametrize("n_in", [1, 2])
def test_free_chain_noise_free(n_in):
    M, C, K, d = free_chain()
    frf = accelerance_from_model(M, C, K, d, FREQ_HZ, d, [d[0], d[-1]][:n_in])
    r = identify_mck(frf)
    assert r.n_rigid_body_modes == 1 and r.real_roots.size == 0
    assert rel(r.M, M) < 1e-7 and rel(r.C, C) < 1e-7 and rel(r.K, K) < 1e-7
    assert not not_physical(r)
    assert any(w.startswith("1 rigid-body mode(s): the 2 roots nearest 0") and "K is singular" in w
               for w in r.warnings)
    # A grounded structure with a mode no input excites, or a massless DOF, gives the same
    # roots (a QA pass's chains), and so do suspension modes the noise hides (the QA's payload
    # on bungees and its stand, 0.3 % noise on the reactions, was told "free-free structure"):
    # the note names those causes too.
    assert any("a mode no input excites and a DOF without mass" in w and "suspension modes" in w
               for w in r.warnings)
    assert r.undamped_freq_hz[0] == 0.0
    # Singular by design (to rounding), on the rigid translation (to step 1's accuracy).
    for A in (r.K, r.C):
        ev, vec = np.linalg.eigh(A)
        assert abs(ev[0]) < 1e-13 * ev[-1]
        assert abs(abs(vec[:, 0] @ np.ones(4) / 2) - 1) < 1e-12 + 1e-7
    assert r.to_json_dict()["n_rigid_body_modes"] == 1


@pytest.mark.parametrize("n_in", [1, 2])
def test_free_chain_report_noise(n_in):
    """Before: roots +-0.7 rad/s (1 input), K 'not positive semi-definite', 'real roots', and
    with 2 inputs 'C has negative eigenvalues'."""
    M, C, K, d = free_chain()
    frf = accelerance_from_model(M, C, K, d, FREQ_HZ, d, [d[0], d[-1]][:n_in])
    r = identify_mck(report_noise_frf(frf, seed=1))
    assert r.n_rigid_body_modes == 1
    assert not not_physical(r), r.warnings
    assert r.checks["K_min_eig_rel"] > -1e-9 and r.checks["C_min_eig_rel"] > -1e-9
    assert rel(r.M, M) < 0.01 and rel(r.K, K) < 0.02
    assert np.allclose(r.natural_freq_hz, ELASTIC_HZ, rtol=0.01)


@pytest.mark.parametrize("seed", [None, 1])
def test_grounded_suspension_below_the_band_is_kept(seed):
    """Springs of 28 N/m at the ends put a suspension mode at 0.60 Hz, below the 1 Hz line:
    a candidate, which the lines resolve (its correction to the mass line is 36 % at 1 Hz),
    so it stays an elastic mode and K stays non-singular."""
    M, C, K, d = free_chain(28.0)
    frf = accelerance_from_model(M, C, K, d, FREQ_HZ, d, [d[0]])
    r = identify_mck(frf if seed is None else report_noise_frf(frf, seed=seed))
    assert r.info["rigid_body"]["tests"], "the suspension roots were not tested"
    assert r.n_rigid_body_modes == 0
    if seed is None:
        # Well-conditioned eigenvectors beat the near-rigid block, whose shape is a real
        # approximation of the mode's slightly complex one (non-proportional dampers).
        assert r.info["rigid_body"]["near_rigid"]["used"] == "eigenvectors"
    f_susp = np.sqrt(2 * 28.0 / 4) / (2 * np.pi)
    assert r.natural_freq_hz[0] == pytest.approx(f_susp, rel=0.01)
    assert rel(r.K, K) < (1e-6 if seed is None else 0.02)


def free_beam():
    """A free-free beam (3 cubic elements, Z and RY at 4 nodes, 2 % modal damping): two
    rigid-body modes, a translation and a rotation."""
    sec = box_section(0.04, 0.04, 0.003)
    K, M, labels = assemble_grillage({i: (0.4 * i, 0.0) for i in range(4)}, [(i, i + 1, sec) for i in range(3)])
    idx = [i for i, lbl in enumerate(labels) if not lbl.endswith("RX")]
    K, M = K[np.ix_(idx, idx)], M[np.ix_(idx, idx)]
    dofs = [labels[i] for i in idx]
    return M, modal_damping(M, K, 0.02), K, dofs


@pytest.mark.parametrize("solver", ["ls", "tls", "stls", "ml"])
def test_free_beam_noise_free_near_rigid_block(solver):
    """Noise-free, the beam's rigid-body shapes carry the rounding of the synthesis (eig(K, M)
    of the FE model gives +-2e-11 there, and modal damping a matching C): data exact to 1e-12
    show it, the likelihood-ratio test keeps the roots near 0 (1e-4 to 6e-3 rad/s, first line
    126 rad/s), and through their nearly parallel eigenvectors Eq. 3.26 lost M (7 times off
    with ml, 1e9 with tls; ls failed in the Schur reordering). Assembled as one near-rigid
    block, M, C, K come back to step 1's accuracy: measured M <= 4.1e-9 and K <= 3.7e-10 over
    the four solvers, C 1.2e-7 (tls) to 1.1e-6 (ml with one BLAS thread; 1.6e-7 with two: where
    the maximum-likelihood refinement stops moves with rounding, and C is what it determines
    least), hence 1e-7 on M, K and 1e-5 on C."""
    M, C, K, dofs = free_beam()
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(20, 6000, 1200), dofs, ["0+Z", "3+Z"])
    r = identify_mck(frf, solver=solver)
    near = r.info["rigid_body"]["near_rigid"]
    assert near["used"] == "near_rigid_block" and near["n_shapes"] == 2
    errors = near["weighted_output_error"]
    assert errors["eigenvectors"] > 1e6 * errors["near_rigid_block"]
    assert rel(r.M, M) < 1e-7 and rel(r.K, K) < 1e-7 and rel(r.C, C) < 1e-5
    assert not any("M is not positive definite" in w or "K is not positive" in w for w in r.warnings)
    wn = np.sqrt(sla.eigh(K, M, eigvals_only=True)[2:]) / (2 * np.pi)
    assert np.allclose(r.undamped_freq_hz[-6:], wn, rtol=1e-7)


def test_free_beam_two_rigid_body_modes_with_noise():
    """The free beam under the report's noise: ``r = 2`` and the rigid block couples a
    translation and a rotation."""
    M, C, K, dofs = free_beam()
    frf = accelerance_from_model(M, C, K, dofs, np.linspace(20, 6000, 1200), dofs, ["0+Z", "3+Z"])
    r = identify_mck(report_noise_frf(frf, seed=1))
    assert r.n_rigid_body_modes == 2
    assert not not_physical(r), r.warnings
    assert rel(r.M, M) < 0.01 and rel(r.K, K) < 0.03  # measured 0.35 % and 1.2 %
    wn = np.sqrt(sla.eigh(K, M, eigvals_only=True)[2:]) / (2 * np.pi)  # 2 % damping: roots within 0.02 %
    assert np.allclose(np.sort(r.natural_freq_hz), np.sort(wn), rtol=0.01)


def test_free_payload_seen_from_20_hz_keeps_a_physical_assembly():
    """The payload of docs/guide.md's free test (examples/setup_sim_free.toml: 16 Z sensors,
    shakers at 11+Z and 16+Z, the hidden 0.25 kg included) hangs on bungees whose 1.3-6.2 Hz
    modes lie below a 20-1500 Hz sweep. Noise: complex Gaussian, 0.02 % of |H| per value (the
    simulated acquisition's median), seed 1, its variance given as an analyser writes it.
    The near-rigid block on those three shapes fits the lines best (16 times lower output
    error), but the mass line it fits from 20 Hz up carries a negative mass on one shape, and
    M, K are not definite; through their eigenvectors M, K are positive definite. The physical
    assembly is kept, and the undamped frequencies of its M, K in the band lie within 0.1 % of
    the roots (measured 0.041 %, at 385 Hz)."""
    from pathlib import Path

    from daq.setup import parse_setup
    from daq.simlab import build_world

    path = Path(__file__).resolve().parents[1] / "examples" / "setup_sim_free.toml"
    setup = parse_setup(path.read_text(), str(path))
    outputs = [f"{n}+Z" for n in (1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 13, 14, 15, 16, 17, 18)]
    ref = build_world(setup).frf(np.geomspace(20.0, 1500.0, 150), outputs=outputs, inputs=["11+Z", "16+Z"])
    rng = np.random.default_rng(1)
    sd = 2e-4 * np.abs(ref.H)
    noise = sd * (rng.standard_normal(ref.H.shape) + 1j * rng.standard_normal(ref.H.shape)) / np.sqrt(2)
    r = identify_mck(dataclasses.replace(ref, H=ref.H + noise, H_var=sd**2))
    near = r.info["rigid_body"]["near_rigid"]
    assert near["problems"] == {"eigenvectors": 0, "near_rigid_block": 2}
    errors = near["weighted_output_error"]
    assert errors["near_rigid_block"] < errors["eigenvectors"]  # the rule, not the fit, decided
    assert near["used"] == "eigenvectors"
    assert np.linalg.eigvalsh(r.M).min() > 0 and np.linalg.eigvalsh(r.K).min() > 0
    in_band = (r.natural_freq_hz > 20) & (r.natural_freq_hz < 1500)
    assert np.max(np.abs(r.undamped_freq_hz[in_band] / r.natural_freq_hz[in_band] - 1)) < 1e-3
