"""Beam elements against closed-form beam theory; the payload simulator's structure; EfI."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from ssid.errors import InputError
from ssid.models.beams import assemble_grillage, box_section
from ssid.models.payload import (
    INTERFACE_DOFS,
    RAIL_BOX,
    Z_DOFS,
    attach_test_stand,
    modal_damping,
    payload_simulator,
    rayleigh_damping,
    z_energy_fraction,
)
from ssid.placement import effective_independence

SEC = box_section(0.05, 0.05, 0.003)
L_BEAM = 1.5


def line_beam(n_el: int, angle_deg: float = 0.0):
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    xy = {i: (c * L_BEAM * i / n_el, s * L_BEAM * i / n_el) for i in range(n_el + 1)}
    return assemble_grillage(xy, [(i, i + 1, SEC) for i in range(n_el)])


def test_free_free_bending_matches_euler_bernoulli():
    """(beta L) = 4.7300, 7.8532, 10.9956 for a free-free beam; 20 cubic elements converge
    to better than 0.05 % on the first three flexible modes."""
    K, M, labels = line_beam(20)
    # Out-of-plane bending only involves Z and RY for a beam along X: drop the twist DOFs.
    idx = [i for i, lbl in enumerate(labels) if not lbl.endswith("RX")]
    lam = sla.eigh(K[np.ix_(idx, idx)], M[np.ix_(idx, idx)], eigvals_only=True)
    f = np.sqrt(np.abs(lam)) / (2 * np.pi)
    flexible = f[2:5]  # two rigid-body modes first
    bl = np.array([4.73004, 7.85320, 10.99561])
    exact = bl**2 / (2 * np.pi * L_BEAM**2) * np.sqrt(SEC.E_pa * SEC.I_m4 / (SEC.rho_kg_m3 * SEC.A_m2))
    assert np.allclose(flexible, exact, rtol=5e-4)
    assert np.all(f[:2] < 1e-3 * flexible[0])


def test_clamped_free_torsion_matches_closed_form():
    K, M, labels = line_beam(40)
    idx = [i for i, lbl in enumerate(labels) if lbl.endswith("RX") and lbl != "0+RX"]
    lam = sla.eigh(K[np.ix_(idx, idx)], M[np.ix_(idx, idx)], eigvals_only=True)
    f1 = np.sqrt(lam[0]) / (2 * np.pi)
    exact = 1 / (4 * L_BEAM) * np.sqrt(SEC.G_pa * SEC.J_m4 / (SEC.rho_kg_m3 * SEC.Ip_m4))
    assert f1 == pytest.approx(exact, rel=2e-4)


def test_element_rotation_invariance():
    """A beam laid at 30 degrees in the plane has the same frequencies as one along X."""
    f0 = sla.eigh(*line_beam(6, 0.0)[:2], eigvals_only=True)
    f30 = sla.eigh(*line_beam(6, 30.0)[:2], eigvals_only=True)
    assert np.allclose(f0[3:], f30[3:], rtol=1e-9)


@pytest.fixture(scope="module")
def payload():
    return payload_simulator()


def test_payload_structure(payload):
    assert payload.n == 52
    assert "9+Z" not in payload.dofs and "10+Z" not in payload.dofs
    nodes = {lbl.split("+")[0] for lbl in payload.dofs}
    assert nodes == {str(i) for i in range(1, 19)}
    assert np.allclose(payload.M, payload.M.T) and np.allclose(payload.K, payload.K.T)
    assert np.linalg.eigvalsh(payload.M).min() > 0
    for lbl in INTERFACE_DOFS + Z_DOFS:
        assert lbl in payload.dofs


def test_payload_suspension_modes(payload):
    lam = sla.eigh(payload.K, payload.M, eigvals_only=True)
    f = np.sqrt(lam) / (2 * np.pi)
    assert np.all(f[:3] < 20.0) and f[3] > 50.0  # three suspension modes, then flexible ones
    # Without the bungee the three would be rigid-body modes (zero frequency).
    free = payload_simulator(bungee_z_n_per_m=0.0, bungee_rot_n_m_per_rad=(0.0, 0.0))
    lam0 = sla.eigh(free.K, free.M, eigvals_only=True)
    assert np.all(np.abs(lam0[:3]) < 1e-6 * lam0[3])


def test_frame_twist_is_carried_by_the_rails_torsion(payload):
    """The 4th mode twists the frame (rail ends 1, 8 against 4, 5; centre nodes 17, 18 at
    rest). With rigid members the frame twists only in torsion: rail ends displaced by +-d
    twist each rail by 4 d / 20 in and each of the four cross-beams by 4 d / 60 in, so with
    the cross-beams' torsion constant 1/16 of the rails' the rails would carry 96 % of the
    stiffness. Member bending takes some of it; if the rails' torsion carries at least 80 %,
    a tenth of their torsion constant leaves at most sqrt(1 - 0.9 * 0.8) = 0.53 of the
    frequency."""
    from dataclasses import replace

    box = RAIL_BOX
    f_hz, _ = z_energy_fraction(payload)
    explicit, _ = z_energy_fraction(payload_simulator(rail=box))
    assert np.allclose(explicit, f_hz, rtol=1e-12)  # the default rail is RAIL_BOX
    soft = payload_simulator(rail=replace(box, J_m4=box.J_m4 / 10))
    f_soft, _ = z_energy_fraction(soft)
    for model, f4 in ((payload, f_hz[3]), (soft, f_soft[3])):
        lam, phi = sla.eigh(model.K, model.M)
        k = int(np.argmin(np.abs(np.sqrt(lam) / (2 * np.pi) - f4)))
        w = phi[model.index(["1+Z", "4+Z", "5+Z", "8+Z", "17+Z", "18+Z"]), k]
        w = w / np.abs(w).max()
        assert np.allclose(np.abs(w[:4]), 1.0, atol=0.05) and np.all(np.abs(w[4:]) < 0.01)
        assert w[0] * w[3] > 0 and w[0] * w[1] < 0 and w[0] * w[2] < 0
    assert f_soft[3] < 0.53 * f_hz[3]
    assert np.allclose(f_soft[:3], f_hz[:3], rtol=0.05)  # the suspension modes hardly move


def test_mpc_ties_slave_to_master(payload):
    """A unit Z of node 18 must move node 9 with it: the constraint stiffens nothing else, so
    the static deflection of 18 and the mass at 18 include the slave's share."""
    full = payload_simulator()
    i18 = full.index(["18+Z"])[0]
    assert full.M[i18, i18] > 0


def test_damping_builders(payload):
    C = modal_damping(payload.M, payload.K, 0.02)
    lam, phi = sla.eigh(payload.K, payload.M)
    Cm = phi.T @ C @ phi
    assert np.allclose(np.diag(Cm), 2 * 0.02 * np.sqrt(lam), rtol=1e-6)
    Cr = rayleigh_damping(payload.M, payload.K, 10.0, 1000.0, 0.02)
    zeta = np.diag(phi.T @ Cr @ phi) / (2 * np.sqrt(lam))
    f = np.sqrt(lam) / (2 * np.pi)
    for f0 in (10.0, 1000.0):
        k = np.argmin(np.abs(f - f0))
        # Rayleigh damping is 2 % exactly at f1 and f2 and close to it nearby.
        a, b = 2 * 0.02 * (2 * np.pi) ** 2 * 10 * 1000 / (2 * np.pi * 1010), 2 * 0.02 / (2 * np.pi * 1010)
        w = 2 * np.pi * f[k]
        assert zeta[k] == pytest.approx(a / (2 * w) + b * w / 2, rel=1e-9)


def test_test_stand_is_nine_dof_per_interface(payload):
    M, K, dofs, T_rel = attach_test_stand(payload)
    assert M.shape == (52 + 27, 52 + 27)
    assert np.linalg.eigvalsh(K).min() > 0  # the stand grounds the assembly
    lam_c = sla.eigh(K, M, eigvals_only=True)
    lam_s = sla.eigh(payload.K, payload.M, eigvals_only=True)
    assert lam_c[0] > 10 * lam_s[0]  # report Table 6.27: the coupled system is much stiffer
    assert T_rel.shape == (3, 79)


def test_effective_independence_picks_observable_dofs():
    rng = np.random.default_rng(0)
    phi = rng.standard_normal((12, 3))
    phi[[2, 5, 9]] *= 1e-3  # nearly blind to the target modes
    kept = effective_independence(phi, 6, [f"d{i}" for i in range(12)])
    assert len(kept) == 6
    assert not {"d2", "d5", "d9"} & set(kept)
    # Mode scaling does not change the choice.
    assert kept == effective_independence(phi * [1.0, 50.0, 0.01], 6, [f"d{i}" for i in range(12)])


def test_effective_independence_keeps_required_dofs():
    """A DOF the test must measure (a driving point) is kept even when it is nearly blind to
    the targets; the other blind ones are still left out; bad requests are refused."""
    rng = np.random.default_rng(0)
    phi = rng.standard_normal((12, 3))
    phi[[2, 5, 9]] *= 1e-3
    labels = [f"d{i}" for i in range(12)]
    kept = effective_independence(phi, 6, labels, required=["d2"])
    assert len(kept) == 6 and "d2" in kept and not {"d5", "d9"} & set(kept)
    with pytest.raises(InputError, match="not a candidate"):
        effective_independence(phi, 6, labels, required=["x"])
    with pytest.raises(InputError, match="more than the 3 to keep"):
        effective_independence(phi, 3, labels, required=labels[:4])


def test_effective_independence_refuses_what_it_cannot_choose_from():
    """More sensors than candidates was a plain ValueError; all-NaN shapes returned DOFs (the
    last three, from a QR of NaNs) and n_keep = 4.5 kept 4, both without a word (QA)."""
    rng = np.random.default_rng(0)
    phi = rng.standard_normal((6, 3))
    with pytest.raises(InputError, match="between the number of modes \\(3\\) and of candidates \\(6\\), got 10"):
        effective_independence(phi, 10)
    with pytest.raises(InputError, match="phi holds NaN or Inf in 12 value"):
        effective_independence(np.full((6, 2), np.nan), 3)
    bad = phi.copy()
    bad[4, 1] = np.inf
    with pytest.raises(InputError, match="phi holds NaN or Inf in 1 value"):
        effective_independence(bad, 4)
    for n_keep in (4.5, "4", True):
        with pytest.raises(InputError, match="n_keep must be a whole number of sensors"):
            effective_independence(phi, n_keep)
    # A whole float is a whole number, and a 1-D shape is one mode: its largest entries win.
    assert effective_independence(phi, 4.0) == effective_independence(phi, 4)
    assert effective_independence(np.array([0.1, 1.0, -0.2, 2.0]), 2) == [1, 3]
