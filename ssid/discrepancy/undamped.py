"""The search for a model file without C: modal damping, one ratio for every mode, as a nuisance.

An undamped nominal model cannot be compared with measured FRFs, so it gets modal damping
``zeta C_1`` (``response.unit_modal_damping``) with one ratio for every mode. That ratio is
not known; worse, the effects sought trade off against it (a grounded damper adds damping to
the modes that move its DOF, a heavily damped oscillator below the band acts as a damper and
a spring). So:

1. ``none`` is judged at its own best ratio: the nominal model fitted alone.
2. The search starts from the ratio read off the measured peaks (``damping.damping_from_data``,
   no model: a nominal fit would be biased by the very effect sought), and alternates: the
   ratio refitted with the leader in place, the search repeated, until the leader is stable.
3. The leading candidates of different effects or DOFs are then each refitted *jointly* with
   the ratio (an outer 1-D search on ``log zeta``, the effect's own fit inside it), and the best
   joint fit decides the ratio of the final search. Without this a candidate fitted at another
   candidate's ratio is judged unfairly.
4. A mass or a spring changes the structure, and modal damping of the changed structure can
   be read two ways: the nominal modes' damping matrix kept (damping that belongs to the
   structure, which a mass does not change: the search's reading), or every mode of the
   changed structure damped alike (what measured peaks of one ratio show). The leading
   candidates that change only M or K are refitted under the second reading too, their
   parameter and ratio together, by exact modal synthesis of the changed structure; the data
   decide, with the candidate's own ratio counted as one more parameter
   (:func:`own_modes_reading`). Without this, on data damped in their own modes a mass was
   named as an oscillator tuned far above the band, whose frequency dependence absorbed the
   difference between the two readings. An oscillator or a damper brings its own damper, and
   the structure's C is kept for them.

The joint fits of step 3 use modal superposition of the nominal modes and the rank-one update
of the candidate's location only, so they cost a few modal syntheses per ratio tried; those of
step 4 solve the changed structure's eigenproblem at every evaluation, and a candidate that
takes that reading is also cross-validated under it (:func:`own_modes_heldout_gain`).
"""

from __future__ import annotations

from functools import partial

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from ..frf import FRFData
from ..io import Model
from ..model_checks import MassNotPositiveDefinite
from ..tam import normal_modes
from .damping import damping_from_data, peak_damping_ratios
from .effects import PARAMETER_KEYS, Effect, apply_effect, effect_dynamic_stiffness, unit_shape
from .fit import fit_one_parameter, fit_oscillator
from .localise import Locations, compress
from .response import fit_global_damping, modal_accelerance, to_inputs, unit_modal_damping
from .search import (
    NONNEGATIVE,
    Candidate,
    OwnModesDamping,
    SearchResult,
    alternate_line_folds,
    rank_candidates,
    rerank_none,
)

__all__ = ["damping_spread_warning", "joint_damping_fit", "modal_location", "own_modes_fit", "own_modes_reading",
           "search_undamped"]

#: Leading candidates (distinct effect and DOFs) refitted jointly with the damping ratio.
N_JOINT = 4
#: Effects that change only the structure's M or K: the ones read also with the changed
#: structure's own modes damped (module docstring, 4).
OWN_MODES_EFFECTS = ("added_mass", "grounded_spring", "coupling_spring")
#: Measured modes whose damping ratios differ by more than this factor cannot share one ratio.
#: Cases of one ratio for all (the bench's, 1-3 %, with any hidden effect but a damper) read
#: 1.0-1.7 off the peaks; a structure on a stand with a dashpot, 0.0014-0.035.
DAMPING_SPREAD = 3.0


def effect_direction(n: int, dofs: list[str], effect: Effect) -> np.ndarray:
    """``u`` of the effect's rank-one change ``delta u u^T``, (n,)."""
    u = np.zeros(n)
    u[dofs.index(effect.dofs[0])] = 1.0
    if len(effect.dofs) == 2:
        u[dofs.index(effect.dofs[1])] = -1.0
    return u


def modal_location(lam, phi, out_idx, in_idx, omega, zeta: float, u: np.ndarray,
                   H: np.ndarray, W: np.ndarray, T: np.ndarray | None = None) -> tuple[Locations, float]:
    """Compressed residual data of the one location ``u`` with modal damping ``zeta``, and RSS_0.

    ``in_idx`` and ``T`` (applied loads) as in :func:`ssid.discrepancy.response.nominal_response`.
    """
    w = np.asarray(omega, dtype=float)[:, None]
    inv_den = 1.0 / (lam[None, :] - w**2 + 2j * zeta * np.sqrt(np.abs(lam))[None, :] * w)
    po, pi = phi[out_idx], phi[in_idx]
    H_nom = -(w[:, :, None] ** 2) * to_inputs(np.einsum("or,kr,ir->koi", po, inv_den, pi, optimize=True), T)
    pu = phi.T @ u
    g_o = (inv_den * pu[None, :]) @ po.T  # (n_freq, n_out)
    g_i = to_inputs((inv_den * pu[None, :]) @ pi.T, T)  # (n_freq, n_in)
    g = inv_den @ pu**2
    R = np.where(W > 0, H - H_nom, 0)
    W2 = W**2
    c, b = compress(w[:, 0], g_o[:, :, None], g_i[:, None, :], W2, W2 * R)
    # The index is a placeholder: the fits use only c, a* and g.
    return Locations.from_cb([[0, -1]], c, b, g[:, None]), float(np.sum(W2 * np.abs(R) ** 2))


def _fit_at(cand: Candidate, loc: Locations, omega: np.ndarray) -> tuple[float, dict]:
    """Remaining cost and parameters of ``cand``'s effect refitted at ``loc``'s one location."""
    if cand.name == "attached_oscillator":
        f = fit_oscillator(omega, loc, np.array([0]))
        return float(f.cost[0]), (f.parameters(0) if np.isfinite(f.cost[0]) else cand.effect.parameters)
    fit = fit_one_parameter(unit_shape(cand.name, omega), loc, nonnegative=cand.name in NONNEGATIVE)
    return float(fit.cost[0]), {PARAMETER_KEYS[cand.name][0]: float(fit.theta[0])}


def joint_damping_fit(cand: Candidate, model: Model, lam, phi, out_idx, in_idx, omega, H, W,
                      zeta0: float, T: np.ndarray | None = None) -> tuple[float, Effect, float]:
    """Damping ratio and effect parameters fitted together: ``(zeta, effect, rss)``.

    Outer: bounded 1-D search on ``log zeta`` within a factor 3 of ``zeta0``; inner: the
    effect's own fit (``fit.fit_one_parameter`` or ``fit.fit_oscillator``) at that ratio.
    """
    u = effect_direction(model.n, model.dofs, cand.effect)
    best: dict = {}

    def rss_of(log_zeta: float) -> float:
        z = float(np.exp(log_zeta))
        loc, rss0 = modal_location(lam, phi, out_idx, in_idx, omega, z, u, H, W, T)
        cost, pars = _fit_at(cand, loc, omega)
        rss = rss0 - float(loc.explained[0]) + cost
        if not np.isfinite(rss):
            return 1e300  # a failed inner fit: finite, so that the outer search stays defined
        if not best or rss < best["rss"]:
            best.update(rss=rss, zeta=z, pars=pars)
        return rss

    with np.errstate(invalid="ignore", over="ignore"):
        minimize_scalar(rss_of, bounds=(np.log(zeta0 / 3), np.log(zeta0 * 3)), method="bounded",
                        options={"xatol": 0.01})
    if not best:
        return zeta0, cand.effect, np.inf
    return best["zeta"], Effect(cand.name, cand.effect.dofs, best["pars"]), best["rss"]


def own_modes_accelerance(model: Model, effect: Effect, zeta: float, out_idx, in_idx, omega) -> np.ndarray:
    """Accelerance of ``model`` changed by ``effect`` (one of OWN_MODES_EFFECTS), every mode of
    the changed structure damped ``zeta``, (n_freq, n_out, n_in); a unit force at each input."""
    M, _, K, _ = apply_effect(model.M, None, model.K, model.dofs, effect)
    lam, phi = normal_modes(M, K)
    return modal_accelerance(lam, phi, out_idx, in_idx, omega, zeta)


def own_modes_fit(cand: Candidate, model: Model, omega, H, W, out_idx, in_idx,
                  zeta0: float) -> tuple[float, Effect, float] | None:
    """``cand`` refitted with its changed structure's own modes damped: ``(zeta, effect, rss)``.

    The effect's one parameter and the ratio are fitted together (``least_squares`` on the
    weighted residuals, from ``cand``'s parameter and ``zeta0``, the ratio within a factor 3
    of ``zeta0`` as in :func:`joint_damping_fit`); ``W`` 0 leaves a value out. None if the
    fit fails.
    """
    key = PARAMETER_KEYS[cand.name][0]
    scale = abs(float(cand.effect.parameters[key])) or 1.0
    m = W > 0
    w, h = W[m], H[m]

    def effect_of(x) -> Effect:
        return Effect(cand.name, cand.effect.dofs, {key: float(x[1] * scale)})

    def residual(x) -> np.ndarray:
        try:
            r = w * (h - own_modes_accelerance(model, effect_of(x), float(np.exp(x[0])), out_idx, in_idx,
                                               omega)[m])
        except MassNotPositiveDefinite:  # a negative mass larger than the DOF's own: no such structure
            return np.full(2 * w.size, 1e100)
        return np.concatenate([r.real, r.imag])

    lz = np.log(zeta0)
    with np.errstate(all="ignore"):
        res = least_squares(residual, [lz, float(np.sign(cand.effect.parameters[key]) or 1.0)],
                            bounds=([lz - np.log(3), -np.inf], [lz + np.log(3), np.inf]), x_scale=[0.1, 0.1])
    rss = float(np.sum(res.fun**2))
    if not np.isfinite(rss) or rss >= 1e100:
        return None
    return float(np.exp(res.x[0])), effect_of(res.x), rss


def own_modes_heldout_gain(cand: Candidate, model: Model, omega, H, W, out_idx, in_idx,
                           H_nominal: np.ndarray) -> float:
    """Two-fold cross-validated decrease of the weighted RSS by ``cand`` under its own modes'
    damping, as :func:`ssid.discrepancy.search.cross_validated_gain` does under the round's C:
    refitted (parameter and ratio) on the even lines, the residual it leaves on the odd ones
    against the round's nominal model's ``H_nominal`` there, and the other way round.

    The round's C cannot stand in: a spring that moves the lowest modes far fits half the
    lines under it into another minimum (a held-out loss of 5e5 where this gives a gain).
    """
    gain = 0.0
    for fit_sel, test_sel in alternate_line_folds(omega.size):
        fit = own_modes_fit(cand, model, omega, H, W * fit_sel[:, None, None], out_idx, in_idx,
                            cand.own_modes.zeta)
        if fit is None:
            return -np.inf
        z, eff, _ = fit
        w2, h = W[test_sel] ** 2, H[test_sel]
        H_test = own_modes_accelerance(model, eff, z, out_idx, in_idx, omega[test_sel])
        gain += float(np.sum(w2 * np.abs(h - H_nominal[test_sel]) ** 2) - np.sum(w2 * np.abs(h - H_test) ** 2))
    return gain


def own_modes_reading(search: SearchResult, model: Model, omega, H, W, out_idx, in_idx, zeta: float) -> None:
    """Give each leading candidate that changes only M or K the reading of the changed
    structure's damping that the data prefer, and re-rank ``search`` in place.

    A candidate takes its own modes' damping (:func:`own_modes_fit`; ``Candidate.own_modes``)
    when that fit's criterion, its ratio counted as one more parameter, beats the round's.
    Not on a test stand: there the named effect's parameters come from the exact noise
    model's fit (``stand_noise``), which rests on the round's C.
    """
    for cand in _leaders(search, N_JOINT):
        if cand.name not in OWN_MODES_EFFECTS:
            continue
        fit = own_modes_fit(cand, model, omega, H, W, out_idx, in_idx, zeta)
        if fit is None:
            continue
        z, eff, rss = fit
        crit = float(search.criterion(rss, eff.n_parameters + 1))
        if crit < cand.criterion:
            M, _, K, _ = apply_effect(model.M, None, model.K, model.dofs, eff)
            cand.effect, cand.rss, cand.criterion = eff, rss, crit
            cand.own_modes = OwnModesDamping(
                z, z * unit_modal_damping(M, K), own_modes_accelerance(model, eff, z, out_idx, in_idx, omega),
                partial(own_modes_heldout_gain, cand, model, omega, H, W, out_idx, in_idx, search.nominal.H))
    rank_candidates(search.candidates)


def _leaders(search: SearchResult, n: int) -> list[Candidate]:
    out, seen = [], set()
    for c in search.candidates:
        key = (c.name, c.effect.dofs)
        if c.name != "none" and key not in seen:
            seen.add(key)
            out.append(c)
        if len(out) >= n:
            break
    return out


def damping_spread_warning(freq_hz: np.ndarray, H: np.ndarray, valid: np.ndarray) -> str | None:
    """A warning if the measured modes' damping ratios (read off the peaks,
    ``damping.peak_damping_ratios``) differ by more than DAMPING_SPREAD: one ratio for every
    mode cannot describe them, and an effect or channel gains may then stand in for damping."""
    f, zeta = peak_damping_ratios(freq_hz, H, valid)
    if zeta.size < 2 or zeta.max() <= DAMPING_SPREAD * zeta.min():
        return None
    lo, hi = int(np.argmin(zeta)), int(np.argmax(zeta))
    return (f"the measured modes' damping ratios range from {zeta[lo]:.2g} ({f[lo]:.4g} Hz) to {zeta[hi]:.2g} "
            f"({f[hi]:.4g} Hz), and the model has no C: one ratio for every mode cannot describe them, so "
            "the effect named (and any channel gains flagged) may stand in for damping the model lacks; "
            "give the model a C (e.g. a test stand's dashpots, or modal damping of the measured ratios)")


def search_undamped(model: Model, data: FRFData, omega, H, W, valid, out_idx, in_idx, search_fn,
                    T: np.ndarray | None = None):
    """The search for a model without C (module docstring).

    ``search_fn(C) -> SearchResult`` runs one search round with damping matrix ``C``;
    ``in_idx`` and ``T`` (applied loads) as in :func:`ssid.discrepancy.response.nominal_response`.

    Returns
    -------
    (search, C, zeta, text): the final search, its damping matrix and ratio, and how the
    ratio was found.
    """
    C1 = unit_modal_damping(model.M, model.K)
    lam, phi = normal_modes(model.M, model.K)

    def nominal_frf(z):
        return modal_accelerance(lam, phi, out_idx, in_idx, omega, z, T=T)

    zeta_nom = fit_global_damping(H, W, nominal_frf)
    rss_none = float(np.sum(W**2 * np.abs(H - nominal_frf(zeta_nom)) ** 2))
    zeta = damping_from_data(data.freq_hz, H, valid)
    how = "median of the measured modes' damping (one pole fitted per CMIF peak)"
    if zeta is None:
        zeta, how = zeta_nom, "fitted with the nominal model (no measured peak could be fitted)"
    search = search_fn(zeta * C1)
    seen: list[tuple] = []
    for _ in range(3):
        eff = search.best.effect
        if eff.name == "none" or (eff.name, eff.dofs) in seen:
            break
        seen.append((eff.name, eff.dofs))
        u = effect_direction(model.n, model.dofs, eff)
        delta = effect_dynamic_stiffness(eff, omega)
        zeta = fit_global_damping(H, W, lambda z, u=u, delta=delta: modal_accelerance(
            lam, phi, out_idx, in_idx, omega, z, u=u, delta=delta, T=T), zeta_range=(zeta / 4, zeta * 4))
        how = "refitted to the FRFs with the effect found in place"
        search = search_fn(zeta * C1)
    joint = []
    for cand in _leaders(search, N_JOINT):
        z, eff, rss = joint_damping_fit(cand, model, lam, phi, out_idx, in_idx, omega, H, W, zeta, T)
        joint.append((float(search.criterion(rss, eff.n_parameters)), z, eff))
    if joint:
        _, z, eff = min(joint, key=lambda t: t[0])
        if (eff.name, eff.dofs) != (search.best.name, search.best.effect.dofs) or abs(np.log(z / zeta)) > 0.01:
            zeta, how = z, f"fitted jointly with {eff.name} at {'-'.join(eff.dofs)}"
            search = search_fn(zeta * C1)
    if T is None:
        own_modes_reading(search, model, omega, H, W, out_idx, in_idx, zeta)
    rerank_none(search, rss_none)
    if search.best.name == "none" and zeta != zeta_nom:
        zeta, how = zeta_nom, "fitted to the FRFs with the nominal model"
        search = search_fn(zeta * C1)
    text = (f"the model has no C: modal damping with one ratio for every mode, zeta = {zeta:.4g} "
            f"({how})")
    return search, zeta * C1, zeta, text
