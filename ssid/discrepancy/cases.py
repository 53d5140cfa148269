"""Seeded test cases with a hidden effect: the workflow's benchmark and its tests.

A case is a nominal model, "measured" FRFs of the nominal model with one effect of the library
hidden in it (or none), partial measurement and noise, and the truth. The workflow is never
shown the truth. Two families of structures:

- ``chain``: random lumped chains of 6-14 masses, grounded at one or both ends, with
  non-proportional damping (dampers laid out unlike the springs); log-spaced lines from below
  the first to above the last mode. Effects at any DOF.
- ``payload``: the report's 52-DOF payload simulator (``ssid.models.payload``) with modal
  damping of 1-3 % per mode, linear lines over 20-650 Hz (the flexible modes). Effects at the
  16 Z DOFs (rotations are never measured, so a kilogram there would mean nothing); a quarter
  of the cases give the nominal model without C (the truth then has one ratio for all modes;
  in half of them, by a separate seeded draw, a hidden mass or spring leaves the nominal modes'
  damping matrix as it was, in the other half every mode of the changed structure has the
  ratio: the two readings of modal damping that ``undamped.py`` tells apart).

Sizes are set by what they do, so that they are comparable across structures: a mass, spring
or coupling spring shifts the most affected natural frequency in the band by 1.5-8 %
(log-uniform); a damper adds 0.4-2 % of critical damping to the most affected mode; an
oscillator is tuned inside the band (damping 1-5 %, raised where needed so that its half-power
band spans at least three lines: a resonance between the lines cannot be measured) with 3-30 %
of the apparent mass of its DOF at its tuning. Noise: relative, 1-3 % RMS (complex Gaussian), plus a floor of 3 % of that
level times the FRF's RMS magnitude; coherence written as an H1 estimate with 20 averages
would have it (two cases in three), and 2 % of the values blanked (one case in three).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..frf import FRFData, accelerance_from_model, receptance
from ..io import Model
from ..models import example_system, frf_on_test_stand
from ..models.lumped import chain_model
from ..models.payload import Z_DOFS, payload_simulator
from ..tam import normal_modes
from .effects import EFFECT_NAMES, Effect, apply_effect
from .response import unit_modal_damping
from .undamped import OWN_MODES_EFFECTS

__all__ = ["STAND_INPUTS", "STAND_REACTIONS", "STRUCTURES", "Case", "make_case", "make_stand_case"]

STRUCTURES = ("chain", "payload")
EFFECTS = EFFECT_NAMES[:-1]
N_AVG = 20


@dataclass
class Case:
    """A nominal model, measured FRFs with a hidden effect, and the truth."""

    seed: int
    structure: str
    nominal: Model
    frf: FRFData
    truth: Effect
    info: dict = field(default_factory=dict)


def _chain(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    n = int(rng.integers(6, 15))
    m = rng.uniform(0.5, 2.0, n)
    kb = rng.uniform(0.5, 2.0, n - 1) * 1e5
    kg = np.zeros(n)
    kg[0] = rng.uniform(0.5, 2.0) * 1e5
    if rng.random() < 0.5:
        kg[-1] = rng.uniform(0.2, 1.0) * 1e5
    cb = rng.uniform(0.2, 1.0, n - 1) * np.sqrt(kb * m[:-1]) * 0.04
    cg = np.zeros(n)
    cg[rng.integers(n)] = rng.uniform(5.0, 20.0)
    return chain_model(m, kb, kg, cb, cg)


def _frequencies(M: np.ndarray, K: np.ndarray) -> np.ndarray:
    lam, _ = normal_modes(M, K)
    return np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi)


def _max_shift(M, K, f0: np.ndarray, in_band: np.ndarray) -> float:
    """Largest relative change of the in-band natural frequencies; inf once K turns indefinite."""
    try:
        f = _frequencies(M, K)[: f0.size]
    except np.linalg.LinAlgError:
        return np.inf
    if f.min() <= 0:
        return np.inf
    return float(np.max(np.abs(f[in_band] / f0[in_band] - 1)))


def _size_for_shift(make, M, C, K, dofs, target: float, sign: float, scale: float,
                    f0: np.ndarray, in_band: np.ndarray) -> float:
    """Parameter (with ``sign``) for which the largest in-band frequency shift is ``target``."""

    def shift(v: float) -> float:
        M2, _, K2, _ = apply_effect(M, C, K, dofs, make(sign * v))
        return _max_shift(M2, K2, f0, in_band)

    lo, hi = 0.0, scale
    for _ in range(60):
        if shift(hi) >= target:
            break
        lo, hi = hi, hi * 2
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if shift(mid) < target else (lo, mid)
    return sign * 0.5 * (lo + hi)


def _pick_effect(rng, name, M, C, K, dofs, site_dofs, pairs, f_band, omega_grid) -> tuple[Effect, dict]:
    f0 = _frequencies(M, K)
    in_band = (f0 >= f_band[0]) & (f0 <= f_band[1])
    if name == "coupling_spring":
        a, b = pairs[rng.integers(len(pairs))]
        target = float(np.exp(rng.uniform(np.log(0.015), np.log(0.08))))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        scale = float(abs(K[dofs.index(a), dofs.index(b)])) * 1e-3 or 1.0
        make = lambda v: Effect(name, (a, b), {"stiffness_n_per_m": v})
        value = _size_for_shift(make, M, C, K, dofs, target, sign, scale, f0, in_band)
        M2, _, K2, _ = apply_effect(M, C, K, dofs, make(value))
        if sign < 0 and not _max_shift(M2, K2, f0, in_band) > 0.5 * target:
            # The joint cannot lose that much stiffness before the structure (its soft
            # suspension modes) turns unstable: a stiffer joint instead.
            value = _size_for_shift(make, M, C, K, dofs, target, 1.0, scale, f0, in_band)
        return make(value), {"target_shift": target}
    p = str(site_dofs[rng.integers(len(site_dofs))])
    i = dofs.index(p)
    if name in ("added_mass", "grounded_spring"):
        target = float(np.exp(rng.uniform(np.log(0.015), np.log(0.08))))
        key = "mass_kg" if name == "added_mass" else "stiffness_n_per_m"
        scale = 1e-3 * (M[i, i] if name == "added_mass" else K[i, i])
        make = lambda v: Effect(name, (p,), {key: v})
        return make(_size_for_shift(make, M, C, K, dofs, target, 1.0, scale, f0, in_band)), {"target_shift": target}
    lam, phi = normal_modes(M, K)
    if name == "grounded_damper":
        dz = float(np.exp(rng.uniform(np.log(0.004), np.log(0.02))))
        wr = np.sqrt(np.abs(lam))
        per_c = np.where(in_band[: wr.size], phi[i] ** 2 / (2 * wr), 0)  # d zeta_r / d c
        return Effect(name, (p,), {"damping_n_s_per_m": dz / float(per_c.max())}), {"target_dzeta": dz}
    # attached oscillator
    fo = float(np.exp(rng.uniform(np.log(f_band[0] * 1.25), np.log(f_band[1] / 1.25))))
    # A resonance the lines resolve: half-power band of at least three lines.
    df = float(np.interp(2 * np.pi * fo, omega_grid, np.gradient(omega_grid))) / (2 * np.pi)
    zo = max(float(rng.uniform(0.01, 0.05)), 1.5 * df / fo)
    mu = float(np.exp(rng.uniform(np.log(0.03), np.log(0.3))))
    wo = 2 * np.pi * fo
    D = np.zeros((M.shape[0], 1))
    D[i, 0] = 1.0
    g = receptance(M, C, K, np.array([wo]), D, D.T)[0, 0, 0]
    m_app = 1.0 / abs(wo**2 * g)
    m = mu * m_app
    eff = Effect(name, (p,), {"mass_kg": m, "stiffness_n_per_m": m * wo**2, "damping_n_s_per_m": 2 * zo * m * wo})
    return eff, {"mass_ratio": mu, "f_o_hz": fo, "zeta_o": zo}


def _noisy(rng, H: np.ndarray, eps: float, coherence: bool, blank: bool) -> FRFData:
    rms = np.sqrt(np.mean(np.abs(H) ** 2, axis=0, keepdims=True))
    var = eps**2 * np.abs(H) ** 2 + (0.03 * eps * rms) ** 2
    noise = np.sqrt(var / 2) * (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape))
    out = FRFData(freq_hz=np.zeros(0), H=H + noise, outputs=[], inputs=[])
    if coherence:
        out.coherence = 1.0 / (1.0 + 2 * N_AVG * var / np.maximum(np.abs(H) ** 2, 1e-300))
        out.n_avg = N_AVG
    if blank:
        valid = rng.random(H.shape) >= 0.02
        out.valid = valid
        out.H = np.where(valid, out.H, np.nan)
    return out


def make_case(seed: int, structure: str | None = None, effect: str | None = None,
              n_lines: int | None = None, undamped_nominal: bool | None = None,
              n_outputs: int | None = None, n_inputs: int | None = None,
              model_error: float = 0.0, own_modes_truth: bool | None = None) -> Case:
    """A seeded case (module docstring).

    Parameters
    ----------
    seed : int
    structure : {"chain", "payload"}, optional
        Random when None.
    effect : str, optional
        An effect name (``"none"`` for a null case); a random effect (never none) when None.
    n_lines : int, optional
        Lines (default 400 for chains, 500 for the payload).
    undamped_nominal : bool, optional
        Give the nominal model without C (payload default: one case in four; chain: never).
    n_outputs, n_inputs : int, optional
        Measured DOFs and inputs (default random: 60-100 % of the chain's DOFs or 8-16 of the
        payload's Z DOFs; 1-3 inputs).
    model_error : float
        Relative RMS of a distributed stiffness error that the truth has and the nominal model
        lacks, ``K_true = S K S`` with ``S = diag(1 + model_error * n)``, ``n`` standard normal
        (0, the default: the nominal model is exact but for the hidden effect).
    own_modes_truth : bool, optional
        For a nominal model without C and a hidden mass or spring: every mode of the changed
        structure damped alike (True) or the nominal modes' damping matrix kept (False);
        default a seeded draw, each half of the time.
    """
    rng = np.random.default_rng(seed)
    structure = structure or STRUCTURES[int(rng.integers(2))]
    name = effect or EFFECTS[int(rng.integers(len(EFFECTS)))]
    if structure == "chain":
        M, C, K, dofs = _chain(rng)
        f = _frequencies(M, K)
        band = (0.7 * f[0], 1.15 * f[-1])
        freq = np.geomspace(band[0], band[1], n_lines or 400)
        n = len(dofs)
        n_out = int(rng.integers(int(np.ceil(0.6 * n)), n + 1))
        n_out = min(n, n_outputs or n_out)
        outputs = [dofs[i] for i in np.sort(rng.choice(n, n_out, replace=False))]
        sites = list(dofs)
        pairs = [(dofs[i], dofs[i + 1]) for i in range(n - 1)]
        undamped = False if undamped_nominal is None else undamped_nominal
        zeta_all = None
    else:
        pm = payload_simulator()
        M, K, dofs = pm.M, pm.K, list(pm.dofs)
        undamped = (rng.random() < 0.25) if undamped_nominal is None else undamped_nominal
        n_modes = M.shape[0]
        zeta_all = rng.uniform(0.01, 0.03) if undamped else rng.uniform(0.01, 0.03, n_modes)
        C = unit_modal_damping(M, K) if undamped else None
        if undamped:
            C = zeta_all * C
        else:
            lam, phi = normal_modes(M, K)
            Mphi = M @ phi
            C = Mphi @ np.diag(2 * zeta_all * np.sqrt(np.abs(lam))) @ Mphi.T
            C = (C + C.T) / 2
        band = (20.0, 650.0)
        freq = np.linspace(band[0], band[1], n_lines or 500)
        n_out = int(rng.integers(8, 17))
        n_out = min(len(Z_DOFS), n_outputs or n_out)
        outputs = [Z_DOFS[i] for i in np.sort(rng.choice(len(Z_DOFS), n_out, replace=False))]
        sites = list(Z_DOFS)
        iz = [dofs.index(d) for d in Z_DOFS]
        pairs = [(dofs[a], dofs[b]) for x, a in enumerate(iz) for b in iz[x + 1:] if K[a, b] != 0]
    n_in = int(rng.integers(1, min(3, len(outputs)) + 1))
    n_in = min(len(outputs), n_inputs or n_in)
    inputs = [outputs[i] for i in np.sort(rng.choice(len(outputs), n_in, replace=False))]
    if name == "none":
        truth, size = Effect("none"), {}
    else:
        truth, size = _pick_effect(rng, name, M, C, K, dofs, sites, pairs, band, 2 * np.pi * freq)
    K_true = K
    if model_error > 0:
        s = 1 + model_error * np.random.default_rng(seed + 7_000_000).standard_normal(K.shape[0])
        K_true = s[:, None] * K * s[None, :]
    M2, C2, K2, d2 = apply_effect(M, C, K_true, dofs, truth)
    own_modes = undamped and truth.name in OWN_MODES_EFFECTS and (
        np.random.default_rng(seed + 9_000_000).random() < 0.5 if own_modes_truth is None else own_modes_truth)
    if own_modes:
        C2 = zeta_all * unit_modal_damping(M2, K2)
    H = accelerance_from_model(M2, C2, K2, d2, freq, outputs, inputs).H
    eps = float(rng.uniform(0.01, 0.03))
    coherence = rng.random() < 2 / 3
    blank = rng.random() < 1 / 3
    meas = _noisy(rng, H, eps, coherence, blank)
    meas.freq_hz, meas.outputs, meas.inputs = freq, outputs, inputs
    nominal = Model(M=M, K=K, C=None if undamped else C, dofs=list(dofs))
    info = {"noise": eps, "coherence": coherence, "blanked": blank, "undamped_nominal": undamped,
            "model_error": model_error,
            "n_dofs": len(dofs), "n_out": len(outputs), "n_in": n_in, **size}
    if undamped:
        info["zeta"] = float(zeta_all)
        info["own_modes_truth"] = bool(own_modes)
    return Case(seed, structure, nominal, meas, truth, info)


#: Inputs and held DOFs (load cells) of :func:`make_stand_case`'s chains.
STAND_INPUTS, STAND_REACTIONS = ["2", "9"], ["0", "13"]


def make_stand_case(seed: int, load_cell_gain: float = 1.0, mass: bool = False) -> Case:
    """A substructure on a test stand whose load cell ``seed % 2`` reads ``load_cell_gain``
    times its force (1: every transducer right), with a hidden mass if ``mass``.

    The seeded 14-DOF chain ``example_system(14, seed)`` held at DOFs 0 and 13 by a flexible
    stand, inputs at 2 and 9, 240 lines over 3-400 Hz; the mass (0.1-0.5 kg) at a free DOF.
    Noise: independent circular complex Gaussian errors of 1 % of each value's magnitude plus
    a floor of 1e-4 of the largest, on accelerances and reactions, stated as variances. The
    nominal model is the chain without the mass. ``info``: the load cell and its gain.
    """
    rng = np.random.default_rng(seed)
    M, C, K, _ = example_system(14, seed=seed)
    dofs = [str(k) for k in range(M.shape[0])]
    truth = Effect("none")
    Mt, Ct, Kt = M, C, K
    if mass:
        site = str(rng.choice([d for d in dofs if d not in STAND_REACTIONS]))
        truth = Effect("added_mass", (site,), {"mass_kg": float(rng.uniform(0.1, 0.5))})
        Mt, Ct, Kt, _ = apply_effect(M, C, K, dofs, truth)
    frf = frf_on_test_stand(Mt, Ct, Kt, dofs, STAND_INPUTS, STAND_REACTIONS, np.linspace(3.0, 400.0, 240))

    def noisy(A):
        var = (0.01 * np.abs(A)) ** 2 + (1e-4 * np.abs(A).max()) ** 2
        return A + np.sqrt(var / 2) * (rng.standard_normal(A.shape) + 1j * rng.standard_normal(A.shape)), var

    frf.H, frf.H_var = noisy(frf.H)
    R, vR = noisy(frf.H_reaction)
    r = seed % 2
    R[:, r, :] *= load_cell_gain
    vR[:, r, :] *= load_cell_gain**2
    frf.H_reaction, frf.H_reaction_var = R, vR
    return Case(seed, "stand", Model(M=M, C=C, K=K, dofs=dofs), frf, truth,
                {"load_cell": STAND_REACTIONS[r], "load_cell_gain": load_cell_gain})
