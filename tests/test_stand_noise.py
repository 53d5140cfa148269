"""The discrepancy search on a test stand with the reactions' noise modelled exactly
(ssid.discrepancy.stand_noise): the 14-DOF example chain bolted at DOFs 0 and 13 to a
flexible stand, FRFs and reactions synthesised from the coupled M, C, K.

Noise model throughout: independent circular complex Gaussian errors of 1 % of each value's
magnitude plus a floor of 1e-4 of the largest, on accelerances and reactions alike
(``test_reaction_loads._noisy``), stated as variances unless a test removes them.

Before the errors-in-variables test, with nothing hidden, the search named an effect (a
damper, spring, mass or oscillator of the noise's size) on 10 of the seeds 1-12, and on all
12 without stated variances."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ssid.discrepancy import find_discrepancy
from ssid.discrepancy.cases import make_stand_case
from ssid.discrepancy.effects import Effect, apply_effect
from ssid.discrepancy.stand_noise import StandNoise, _GainsCost, eiv_cost
from ssid.frf import applied_loads
from ssid.io import Model
from ssid.models import example_system, frf_on_test_stand

from test_reaction_loads import INPUTS, REACTIONS, _noisy, _on_stand, _substructure, _with_load_cell_gain


def _brute_force_cost(H, W2, H_load, T, var_T) -> float:
    """``sum r^H Sigma^-1 r`` with each line's covariance built and solved, blanked values dropped."""
    r = H - np.einsum("kol,kli->koi", H_load, T)
    total = 0.0
    for k in range(H.shape[0]):
        for j in range(H.shape[2]):
            keep = W2[k, :, j] > 0
            if keep.any():
                A = H_load[k][keep]
                S = np.diag(1 / W2[k, keep, j]) + (A * var_T[k, :, j]) @ A.conj().T
                total += np.real(r[k, keep, j].conj() @ np.linalg.solve(S, r[k, keep, j]))
    return total


def _null_case(seed: int) -> tuple[Model, object]:
    M, C, K, dofs = _substructure()
    return Model(M=M, C=C, K=K, dofs=dofs), _noisy(_on_stand(M, C, K, dofs), 0.01, seed)


def test_the_woodbury_cost_is_the_per_line_covariance_solve_with_blanked_values_dropped():
    model, frf = _null_case(1)
    loads = applied_loads(frf)
    H_load = loads.model_accelerance(model.M, model.C, model.K, model.dofs, frf.omega, frf.outputs)
    W2 = 1 / frf.H_var
    W2[5, 3, 1] = 0.0
    W2[7, :, 0] = 0.0  # a whole line of one input blanked
    cost = eiv_cost(frf.H, W2, H_load, loads.T, loads.var)
    assert cost == pytest.approx(_brute_force_cost(frf.H, W2, H_load, loads.T, loads.var), rel=1e-10)


def test_the_gains_cost_is_the_cost_of_the_scaled_data_and_its_gradient_is_exact():
    # A load cell at x 0.5 and gains off 1 by a few per cent: the value against eiv_cost with
    # the gains applied, the hand-written gradient against central differences.
    model, frf = _null_case(3)
    frf = _with_load_cell_gain(frf, 1, 0.5)
    loads = applied_loads(frf)
    H_load = loads.model_accelerance(model.M, model.C, model.K, model.dofs, frf.omega, frf.outputs)
    W = 1 / np.sqrt(frf.H_var)
    W[3, 2, 1] = 0.0
    f = _GainsCost(StandNoise.build(frf.H, W, loads, frf.outputs, model.dofs), H_load, frf.inputs, frf.reactions)
    rng = np.random.default_rng(0)
    a, b, g = 1 + 0.05 * rng.standard_normal(14), 1 + 0.05 * rng.standard_normal(2), np.array([1.1, 1.7])
    cost, d_a, d_b, d_g = f(a, b, g)
    T, var = loads.T.copy(), loads.var.copy()
    for j, lbl in enumerate(frf.inputs):
        T[:, loads.dofs.index(lbl), j] *= b[j]
    for r, lbl in enumerate(frf.reactions):
        T[:, loads.dofs.index(lbl), :] *= g[r]
        var[:, loads.dofs.index(lbl), :] *= g[r] ** 2
    assert cost == pytest.approx(eiv_cost(frf.H, W**2, a[None, :, None] * H_load, T, var), rel=1e-10)
    x, grad = np.concatenate([a, b, g]), np.concatenate([d_a, d_b, d_g])

    def F(y):
        return f(y[:14], y[14:16], y[16:], grad=False)

    h = 1e-6
    fd = np.array([(F(x + h * e) - F(x - h * e)) / (2 * h) for e in np.eye(x.size)])
    # Central differences err by about eps |f| / h plus h^2 times the third derivative:
    # 3e-9 of the largest component here; a wrong term is wrong at order one.
    assert np.max(np.abs(fd - grad)) < 1e-6 * np.max(np.abs(grad))


def test_at_the_true_model_the_cost_is_the_number_of_values_within_its_spread():
    # Each whitened complex residual has E|z|^2 = 1 and variance 1, so the sum over N values
    # is N +- sqrt(N); a per-value treatment of the reactions' noise has no such property.
    for seed in (1, 2, 3):
        model, frf = _null_case(seed)
        loads = applied_loads(frf)
        H_load = loads.model_accelerance(model.M, model.C, model.K, model.dofs, frf.omega, frf.outputs)
        n = frf.H.size
        cost = eiv_cost(frf.H, 1 / frf.H_var, H_load, loads.T, loads.var)
        assert abs(cost - n) < 4 * np.sqrt(n), (seed, cost, n)


def test_with_nothing_hidden_on_a_stand_and_stated_variances_no_effect_is_named():
    # Before: an effect at a held DOF named on 10 of the seeds 1-12.
    turned_down = 0
    for seed in range(1, 7):
        model, frf = _null_case(seed)
        res = find_discrepancy(model, frf)
        assert res.effect.name == "none", (seed, res.effect.describe())
        assert "stated variance" in res.info["noise"]["reactions"]
        checks = res.info["cross_validation"]["checks"]
        turned_down += any(not c["stand_noise"]["passed"] for c in checks if "stand_noise" in c)
    # Leaders that the per-value weights and the cross-validation let through, the exact
    # noise model turned down.
    assert turned_down >= 2


def test_without_stated_variances_the_reactions_noise_is_estimated_and_mostly_no_effect_is_named():
    # A UFF exchange states no variances: both are estimated from roughness. All 12 of the
    # seeds 1-12 give none. With second differences (which hold some of the FRFs' curvature at
    # resonances) 11 did, seed 12 naming a mass at a held DOF; with those binned by the power
    # of their own lines, a reaction's floor came out a tenth of the truth where it is below
    # it, and 8 did;
    # before the reactions' noise was estimated, none of them did (an effect at a held DOF
    # every time), and the calibration check flagged the held DOF's accelerometer on each of
    # the seeds 1-6 (x 0.09-0.14); scored with the reactions' noise modelled exactly, on none.
    named = []
    for seed in range(1, 13):
        model, frf = _null_case(seed)
        res = find_discrepancy(model, dataclasses.replace(frf, H_var=None, H_reaction_var=None))
        assert "from their roughness" in res.info["noise"]["reactions"]
        assert not res.info["calibration"]["flagged"], res.info["calibration"]["text"]
        assert res.info["calibration"]["scored"].startswith("errors in variables")
        named.append(res.effect.name)
    assert named.count("none") >= 11, named


@pytest.mark.parametrize("truth, seed", [
    (Effect("grounded_spring", ("13",), {"stiffness_n_per_m": 2e5}), 4),
    (Effect("added_mass", ("0",), {"mass_kg": 0.1}), 4),
    (Effect("coupling_spring", ("12", "13"), {"stiffness_n_per_m": 2000.0}), 4),
    # The search's per-value ranking put an oscillator tuned below the band first on this
    # seed (0.99 kg, 3010 N/m, 20.6 N s/m: a damper there); only the leader was checked, and
    # it passed. Of the three first candidates checked, the damper is the better under the
    # exact noise model (at 20 and 50 N s/m, seeds 1-6: the oscillator had been named on 6
    # of 12, the damper now on 12, at 16-26 and 46-56 N s/m).
    (Effect("grounded_damper", ("13",), {"damping_n_s_per_m": 20.0}), 1),
], ids=lambda x: x.name if isinstance(x, Effect) else str(x))
def test_an_effect_at_a_held_dof_is_found_with_the_errors_in_variables_estimate(truth, seed):
    M, C, K, dofs = _substructure()
    Mt, Ct, Kt, _ = apply_effect(M, C, K, dofs, truth)
    frf = _noisy(_on_stand(Mt, Ct, Kt, dofs), 0.01, seed)
    res = find_discrepancy(Model(M=M, C=C, K=K, dofs=dofs), frf)
    assert res.effect.name == truth.name and set(res.effect.dofs) == set(truth.dofs), res.effect.describe()
    named = [c for c in res.info["cross_validation"]["checks"] if c["named"]]
    assert len(named) == 1
    check = named[0]
    assert check["passed"] and check["stand_noise"]["delta_criterion"] < 0
    assert all(c["stand_noise"]["delta_criterion"] >= check["stand_noise"]["delta_criterion"]
               for c in res.info["cross_validation"]["checks"] if c["passed"])
    # The named parameters are the refit's, and the listed winner agrees with the result.
    assert res.effect.parameters == check["stand_noise"]["parameters"]
    first = res.candidates[0]
    assert first["parameters"] == res.effect.parameters
    assert first["gap_after"] == pytest.approx(res.gap_after, rel=1e-6)
    # Seeds 1-6 gave 0.2-1.2 % off for the spring, the mass and the coupling spring; the
    # damper is seen far less (the stand's own damping and the reactions' noise at its DOF:
    # 16-26 N s/m for 20 on seeds 1-6; 21.1 on this one).
    (key, value), = truth.parameters.items()
    rel = 0.1 if truth.name == "grounded_damper" else 0.03
    assert res.effect.parameters[key] == pytest.approx(value, rel=rel)


@pytest.mark.parametrize("seed, gain", [(10002, 1 / 9.80665), (10012, 1 / 9.80665), (10018, -1.0)])
def test_with_a_wrong_load_cell_and_nothing_hidden_the_corrected_search_names_none(seed, gain):
    """``bench/discrepancy_accuracy.py``'s load-cell cases of these seeds (the chain of the
    seed, its load cell ``seed % 2`` reading ``gain`` times the force, nothing hidden). With
    the gains of the per-value fit, the data corrected by them named a 117 N/m coupling
    spring, a -6 g and a -12 g mass; refitted with the reactions' noise modelled exactly,
    none. Each gain is a unit slip (kgf for N, a reversed cell), which the reactions' choice
    now finds itself (fitted 0.108, within 20 % of 1/9.81, or -0.99) since it compares by the
    median log ratio: the search on the reactions divided by it names none and flags nothing,
    the load cells' gains within 0.2 % of 1, the gap 0.99-1.0."""
    M, C, K, _ = example_system(14, seed=seed)
    dofs = [str(k) for k in range(M.shape[0])]
    r = seed % 2
    frf = _with_load_cell_gain(_noisy(_on_stand(M, C, K, dofs), 0.01, seed), r, gain)
    res = find_discrepancy(Model(M=M, C=C, K=K, dofs=dofs), frf)
    cal = res.info["calibration"]
    assert res.info["reactions"]["load_cell_factor"] == {REACTIONS[r]: gain}, res.info["reactions"]["text"]
    assert not cal["flagged"] and res.effect.name == "none", (cal["text"], res.effect.describe())
    assert all(g == pytest.approx(1.0, rel=0.002) for g in cal["reaction_gain"].values()), cal["reaction_gain"]
    assert res.gap_after < 1.05


def test_a_record_too_short_to_estimate_the_reactions_noise_says_it_takes_them_as_exact():
    # 40 lines: fewer than the two-level roughness fit needs (4 per bin, 14 bins). A made-up
    # level would set the reactions' noise against the accelerances' at random.
    M, C, K, dofs = _substructure()
    frf = _noisy(frf_on_test_stand(M, C, K, dofs, INPUTS, REACTIONS, np.linspace(3.0, 400.0, 40)), 0.01, 1)
    res = find_discrepancy(Model(M=M, C=C, K=K, dofs=dofs), dataclasses.replace(frf, H_var=None, H_reaction_var=None))
    assert res.info["noise"]["reactions"].startswith("taken as exact")
    assert all("stand_noise" not in c for c in res.info["cross_validation"]["checks"])
    assert res.info["calibration"]["scored"] == "per-value weighted residual"


def test_a_load_cell_in_kgf_beside_a_hidden_mass_is_corrected_until_the_mass_is_named():
    """``bench/discrepancy_accuracy.py``'s load-cell case of seed 10017
    (``cases.make_stand_case``): the chain of the seed on its stand, a hidden 0.21 kg mass at DOF 12 beside the held DOF
    13, whose load cell reads in kgf; noise 1 % of each value plus a floor of 1e-4 of the
    largest, stated. The reactions' choice does not take the kgf (the mass biases the fitted
    factor to 0.118, and dividing by 1/9.81 does not halve the gap), so the calibration check
    flags the cell and the search runs on the data corrected by the gains. With two fixed
    sweeps of search and gain refit, the held DOF's accelerometer kept x 0.46 and an
    oscillator at 12 was named; iterated until the effect and the gains settle, the mass."""
    case = make_stand_case(10017, 1 / 9.80665, mass=True)
    truth = case.truth
    res = find_discrepancy(case.nominal, case.frf)
    assert truth.dofs == ("12",) and case.info["load_cell"] == "13"
    assert res.info["reactions"]["load_cell_factor"] == {}
    fix = res.info["calibration"]["with_gains_corrected"]
    assert (fix["effect"], fix["dofs"]) == ("added_mass", ["12"]), fix["text"]
    assert fix["parameters"]["mass_kg"] == pytest.approx(truth.parameters["mass_kg"], rel=0.02)
    assert fix["reaction_gain"]["13"] == pytest.approx(1 / 9.80665, rel=0.02)
    assert all(g == pytest.approx(1.0, abs=0.01) for g in fix["output_gain"].values()), fix["output_gain"]
    assert fix["settled"] and 2 < fix["sweeps"] < 16, fix["sweeps"]
