"""One round of the candidate search: every effect at every plausible location, fitted and ranked.

Ranking criterion: the extended Bayesian information criterion (EBIC, Chen and Chen 2008,
with ``gamma = 1``) of a Gaussian model of the weighted FRF residuals,

    EBIC = N ln(RSS / N) + k ln N + 2 ln(n_models)

``N`` real data values (twice the number of valid complex FRF values), ``RSS`` the weighted
residual sum of squares after the effect, ``k`` its parameter count, ``n_models`` the number of
one-effect models tried: every one-DOF effect at every DOF, every coupling pair, and for the
oscillator every DOF times the tunings screened (it picks its tuning too). ``none`` has
``EBIC = N ln(RSS_0 / N)``. The noise level is each model's own ``RSS / N`` (the weights from
``H_var``, coherence or roughness fix the relative level of every value), so a misjudged
absolute noise level does not tilt the decision. ``k ln N`` is the plain BIC's price per
parameter; ``2 ln(n_models)`` pays for having picked the best of that many models, without
which some location would fit noise well enough to beat ``none`` in null data.

The winner must also survive a two-fold cross-validation over alternate lines
(:func:`cross_validated_gain`): refitted on the even lines it must lower the residual of the
odd lines, and the other way round. Noise that a model happens to fit (a narrow resonance on a
few lines whose noise level was underestimated) does not predict the lines in between; a
real effect does.

Coupling springs are tried between DOFs that K already connects (plus the pairs among the
best-localised DOFs, ``localise.candidate_pairs``). Oscillators, the one costly fit, are
screened at every DOF by a linear fit over a grid of tunings and fitted exactly at the best
screened DOFs, and beyond those only where ``N ln((RSS_0 - E)/N)`` plus their penalty could
still beat the best criterion so far (an exact bound: no change at a location removes more
than its ``E``) and the screened criterion is within a margin of it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .effects import (
    ONE_DOF_EFFECTS,
    PARAMETER_KEYS,
    Effect,
    effect_dynamic_stiffness,
    unit_shape,
)
from .fit import (
    OSC_N_FREQ,
    OscillatorFit,
    effect_a,
    fit_one_parameter,
    fit_oscillator,
    oscillator_screening,
)
from .localise import Locations, candidate_pairs, pair_locations, single_dof_locations
from .response import NominalResponse, nominal_response, receptance_entries

__all__ = [
    "CRITERION_NAME",
    "Candidate",
    "OwnModesDamping",
    "adopt_parameters",
    "alternate_line_folds",
    "SearchResult",
    "candidate_frf",
    "candidate_location",
    "cross_validated_gain",
    "frf_change",
    "rank_candidates",
    "rerank_none",
    "search_round",
]

CRITERION_NAME = "EBIC: N ln(RSS/N) + k ln N + 2 ln(n_models)"
#: Effects whose parameter must not be negative (a negative damper feeds energy in).
NONNEGATIVE = ("grounded_damper",)
#: An effect that changes no model FRF value by more than this fraction of the value (about
#: 0.01 dB in magnitude, 0.06 degrees in phase) is negligible, however clearly the data show
#: it: ten times below what a calibrated accelerometer or force gauge resolves (1-2 %), so
#: no model updated with it would predict anything measurably different. On the workflow's
#: benchmark (150 effects shifting a frequency by 1.5-8 % or adding 0.4-2 % of critical
#: damping) the floor changes no result; the smallest effect of the stand tests (a 20 N s/m
#: damper at a held DOF) changes some value by 27 %. The demo's second round had named a
#: 1e-7 kg oscillator that changes none by more than 5e-5, statistically clear under its
#: tiny noise.
NEGLIGIBLE_CHANGE = 1e-3
#: Values further below their FRF's peak than this (60 dB) count as if at that depth in
#: :func:`frf_change`: at an antiresonance's bottom any effect changes the value by a large
#: fraction of itself.
CHANGE_FLOOR = 1e-3
#: Oscillators are always fitted at this many best-screened DOFs (so the list shows them) ...
OSC_MIN_DOFS = 3
#: ... and beyond them only where the screened criterion is within this margin of the best.
SCREEN_MARGIN = 30.0


@dataclass
class OwnModesDamping:
    """A candidate's model damped in its own modes (a model file without C, ``undamped.py``).

    Attributes
    ----------
    zeta : float
        The damping ratio of every mode of the changed structure, fitted with the effect.
    C : (n, n)
        The changed structure's damping matrix, ``zeta C_1(M', K')``.
    H : (n_freq, n_out, n_in)
        Its accelerance at the round's lines.
    heldout_gain : callable
        ``() -> float``: :func:`cross_validated_gain` under this reading (computed when asked:
        it costs four fits).
    """

    zeta: float
    C: np.ndarray
    H: np.ndarray
    heldout_gain: Callable[[], float]


@dataclass
class Candidate:
    """One effect at one location, fitted.

    Attributes
    ----------
    effect : Effect
    rss : float
        Weighted residual sum of squares (complex values, unit noise) after the effect.
    criterion : float
        EBIC (lower is better).
    explained : float
        Localisation ``E`` of the location (0 for none).
    location : tuple or None
        ``("dof", j)`` or ``("pair", j)``: index into the round's Locations; None for none.
    delta_criterion : float
        ``criterion`` minus the best candidate's.
    own_modes : OwnModesDamping or None
        Set when the candidate fits better with the changed structure's own modes damped
        than with the round's C kept; its RSS and parameters are then those of that fit.
    rejected : str or None
        Why the candidate was moved below ``none`` (:func:`demote`), None if it was not.
    fitted_criterion : float or None
        A rejected candidate's criterion before it was moved: the candidates moved below
        ``none`` keep their order by it.
    """

    effect: Effect
    rss: float
    criterion: float
    explained: float
    location: tuple | None = None
    delta_criterion: float = 0.0
    own_modes: OwnModesDamping | None = None
    rejected: str | None = None
    fitted_criterion: float | None = None

    @property
    def name(self) -> str:
        return self.effect.name


@dataclass
class SearchResult:
    """A ranked search (best first) and what is needed to rebuild any candidate's FRFs."""

    candidates: list[Candidate]
    nominal: NominalResponse
    singles: Locations
    pairs: Locations
    rss0: float
    n_real: int
    n_valid: int
    n_models: int
    tried: dict = field(default_factory=dict)

    @property
    def best(self) -> Candidate:
        return self.candidates[0]

    def gap(self, rss: float) -> float:
        """The gap a weighted residual sum ``rss`` leaves: its RMS per valid complex value
        (1 = noise level)."""
        return float(np.sqrt(rss / self.n_valid))

    def none(self) -> Candidate:
        return next(c for c in self.candidates if c.name == "none")

    def best_of(self, name: str) -> Candidate | None:
        return next((c for c in self.candidates if c.name == name), None)

    def criterion(self, rss, k: int):
        """EBIC of a model with ``k`` parameters leaving ``rss`` (scalar or array)."""
        rss = np.maximum(np.asarray(rss, dtype=float), 1e-300)
        pen = 0.0 if k == 0 else k * np.log(self.n_real) + 2 * np.log(max(self.n_models, 1))
        return self.n_real * np.log(rss / self.n_real) + pen


def search_round(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    dofs: list[str],
    omega: np.ndarray,
    H_meas: np.ndarray,
    W: np.ndarray,
    out_idx: np.ndarray,
    in_idx: np.ndarray,
    n_top_pairs: int = 6,
    T: np.ndarray | None = None,
) -> SearchResult:
    """Try every effect of the library on the model (M, C, K) against the measured FRFs.

    Parameters
    ----------
    M, C, K : (n, n)
        The model (``C`` may be None: undamped).
    dofs : list of str
        Its labels.
    omega : (n_freq,) rad/s
    H_meas, W : (n_freq, n_out, n_in)
        Measured accelerance and weights ``1/sigma`` (0 where not valid).
    out_idx, in_idx : int arrays
        Model indices of the outputs and inputs (with ``T``: of the load DOFs).
    T : (n_freq, n_load, n_in) complex, optional
        Applied loads per unit input (a substructure on a test stand also feels the
        measured reactions, ``ssid.frf.AppliedLoads``); None: a unit force at each input.

    Returns
    -------
    SearchResult with every candidate tried, ranked by EBIC (best first).
    """
    nom = nominal_response(M, C, K, omega, out_idx, in_idx, T)
    valid = W > 0
    n_valid = int(valid.sum())
    with np.errstate(over="ignore", invalid="ignore"):
        R = np.where(valid, H_meas - nom.H, 0)
        rss0 = float(np.sum(W**2 * np.abs(R) ** 2))
    # No weight left (the values' variances through the model are not finite), or a residual
    # that is not a number: every gap and criterion would be NaN.
    if not n_valid or not np.isfinite(rss0):
        raise InputError("the model's response at these lines is not a finite number (its M and K so far from the "
                         "data's scale that floating point overflows?)")
    singles = single_dof_locations(nom, W, R)
    pairs = _pairs(M, C, K, omega, nom, W, R, singles, n_top_pairs)
    n = len(dofs)
    n_models = len(ONE_DOF_EFFECTS) * n + pairs.n + n * OSC_N_FREQ
    out = SearchResult([], nom, singles, pairs, rss0, 2 * n_valid, n_valid, n_models)
    cands = out.candidates
    cands.append(Candidate(Effect("none"), rss0, float(out.criterion(rss0, 0)), 0.0))
    for name in ONE_DOF_EFFECTS:
        fit = fit_one_parameter(unit_shape(name, omega), singles, nonnegative=name in NONNEGATIVE)
        rss = rss0 - singles.explained + fit.cost
        crit = out.criterion(rss, 1)
        key = PARAMETER_KEYS[name][0]
        for j in range(n):
            eff = Effect(name, (dofs[singles.index[j, 0]],), {key: float(fit.theta[j])})
            cands.append(Candidate(eff, float(rss[j]), float(crit[j]), float(singles.explained[j]), ("dof", j)))
    if pairs.n:
        fit = fit_one_parameter(unit_shape("coupling_spring", omega), pairs)
        rss = rss0 - pairs.explained + fit.cost
        crit = out.criterion(rss, 1)
        for j in range(pairs.n):
            p, q = pairs.index[j]
            eff = Effect("coupling_spring", (dofs[p], dofs[q]), {"stiffness_n_per_m": float(fit.theta[j])})
            cands.append(Candidate(eff, float(rss[j]), float(crit[j]), float(pairs.explained[j]), ("pair", j)))
    osc = _oscillators(omega, out, min(c.criterion for c in cands))
    for j in np.flatnonzero(np.isfinite(osc.cost)):
        rss = rss0 - singles.explained[j] + osc.cost[j]
        eff = Effect("attached_oscillator", (dofs[singles.index[j, 0]],), osc.parameters(j))
        cands.append(Candidate(eff, float(rss), float(out.criterion(rss, 3)), float(singles.explained[j]), ("dof", j)))
    rank_candidates(cands)
    out.tried = {name: n for name in ONE_DOF_EFFECTS}
    out.tried.update(coupling_spring=pairs.n, attached_oscillator=int(np.isfinite(osc.cost).sum()),
                     attached_oscillator_screened=n * OSC_N_FREQ, none=1)
    return out


def _pairs(M, C, K, omega, nom, W, R, singles: Locations, n_top: int) -> Locations:
    """Coupling-spring locations: the pairs of ``localise.candidate_pairs``."""
    ranked = np.argsort(-singles.explained, kind="stable")
    pair_idx = candidate_pairs(K, ranked, n_top=n_top)
    m = pair_idx.shape[0]
    if m == 0:
        empty = np.zeros((omega.size, 0), dtype=complex)
        return pair_locations(nom, W, R, pair_idx, empty, empty)
    rows = np.concatenate([pair_idx[:, 0], pair_idx[:, 1]])
    cols = np.concatenate([pair_idx[:, 1], pair_idx[:, 0]])
    Gx = receptance_entries(M, C, K, omega, rows, cols)
    return pair_locations(nom, W, R, pair_idx, Gx[:, :m], Gx[:, m:])


def rank_candidates(cands: list[Candidate]) -> None:
    """Sort by criterion (in place; those moved below ``none`` by their criterion before) and
    set each ``delta_criterion`` relative to the best."""
    cands.sort(key=lambda c: (c.criterion, 0.0 if c.fitted_criterion is None else c.fitted_criterion))
    for c in cands:
        c.delta_criterion = c.criterion - cands[0].criterion


def rerank_none(search: SearchResult, rss: float) -> None:
    """Give ``none`` a lower RSS found elsewhere (its own best damping) and re-rank in place."""
    none = search.none()
    if rss < none.rss:
        none.rss = float(rss)
        none.criterion = float(search.criterion(rss, 0))
        rank_candidates(search.candidates)


def demote(search: SearchResult, cand: Candidate, why: str) -> None:
    """Move ``cand`` below ``none`` (it failed its checks: ``why``) and re-rank in place."""
    if cand.fitted_criterion is None:
        cand.fitted_criterion = cand.criterion
    cand.criterion = max(cand.criterion, search.none().criterion + 1e-9)
    cand.rejected = why
    rank_candidates(search.candidates)


def adopt_parameters(search: SearchResult, cand: Candidate, effect: Effect) -> None:
    """Give the validated leader ``cand`` the parameters of ``effect`` (same effect and DOFs,
    refitted elsewhere) and keep it first.

    Its RSS and criterion become those of the new parameters under the search's weights,
    from the compressed data of its location; the others' ``delta_criterion`` are relative
    to it (negative for one that the search's weights alone would now rank higher).
    """
    loc, j = candidate_location(search, cand)
    a = effect_a(effect_dynamic_stiffness(effect, search.nominal.omega), loc.g[:, j])
    cand.own_modes = None  # refitted with the round's C
    rss = search.rss0 - float(loc.explained[j]) + float(np.sum(loc.c[:, j] * np.abs(a - loc.astar[:, j]) ** 2))
    cand.effect, cand.rss = effect, rss
    cand.criterion = float(search.criterion(rss, effect.n_parameters))
    rank_candidates(search.candidates)
    search.candidates.remove(cand)
    search.candidates.insert(0, cand)
    for c in search.candidates:
        c.delta_criterion = c.criterion - cand.criterion


def _oscillators(omega, search: SearchResult, best_so_far: float) -> OscillatorFit:
    """Fit oscillators where they could win, in order of their screened cost.

    The cheap linear screening (``fit.oscillator_screening``) orders the DOFs; exact fits run
    at the first OSC_MIN_DOFS and then while both the exact bound (``E``) and the screened
    criterion (within SCREEN_MARGIN) say the DOF could still beat the best so far.
    """
    singles, rss0 = search.singles, search.rss0
    total = OscillatorFit.empty(singles.n)
    left, screening = oscillator_screening(omega, singles)
    approx = rss0 - singles.explained + left  # screened RSS after an oscillator at each DOF
    best = best_so_far
    for rank, j in enumerate(np.argsort(approx, kind="stable")):
        bound = float(search.criterion(rss0 - singles.explained[j], 3))
        screened = float(search.criterion(approx[j], 3))
        if rank >= OSC_MIN_DOFS and (bound >= best or screened >= best + SCREEN_MARGIN):
            continue
        one = fit_oscillator(omega, singles, np.array([j]), screening)
        for name in ("mass_kg", "omega_o", "zeta_o", "cost"):
            getattr(total, name)[j] = getattr(one, name)[j]
        if np.isfinite(one.cost[j]):
            best = min(best, float(search.criterion(rss0 - singles.explained[j] + one.cost[j], 3)))
    return total


def candidate_location(search: SearchResult, cand: Candidate) -> tuple[Locations, int]:
    """The compressed data of ``cand``'s location and its index in them (``cand`` not none)."""
    kind, j = cand.location
    return (search.singles if kind == "dof" else search.pairs), j


def alternate_line_folds(n_lines: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The two folds of the cross-validation over alternate lines: ``(fit, test)`` masks,
    (n_lines,) each, even lines fitted and odd tested, then the other way round."""
    even = np.arange(n_lines) % 2 == 0
    return (even, ~even), (~even, even)


def cross_validated_gain(search: SearchResult, cand: Candidate) -> float:
    """Two-fold cross-validated decrease of the weighted RSS by ``cand`` over alternate lines.

    The candidate's parameters are refitted on the even lines and the residual it leaves on
    the odd lines is compared with the nominal model's there (and the other way round); the
    two held-out decreases are summed. About ``+k`` (parameters) below zero for a model that
    only fits noise; large and positive for a real effect.
    """
    if cand.location is None:
        return 0.0
    if cand.own_modes is not None:
        return cand.own_modes.heldout_gain()
    loc, j = candidate_location(search, cand)
    one = loc.subset(np.array([j]))
    omega = search.nominal.omega
    gain = 0.0
    for fit_sel, test_sel in alternate_line_folds(omega.size):
        part = one.lines(fit_sel)
        if cand.name == "attached_oscillator":
            f = fit_oscillator(omega[fit_sel], part, np.array([0]), resolution=omega)
            if not np.isfinite(f.cost[0]):
                return -np.inf
            delta = effect_dynamic_stiffness(Effect(cand.name, cand.effect.dofs, f.parameters(0)), omega)
        else:
            theta = fit_one_parameter(unit_shape(cand.name, omega[fit_sel]), part,
                                      nonnegative=cand.name in NONNEGATIVE).theta[0]
            delta = theta * unit_shape(cand.name, omega)
        test = one.lines(test_sel)
        a = effect_a(delta[test_sel], test.g[:, 0])
        gain += float(test.explained[0] - np.sum(test.c[:, 0] * np.abs(a - test.astar[:, 0]) ** 2))
    return gain


def frf_change(search: SearchResult, cand: Candidate) -> float:
    """Largest relative change ``|H_with - H| / |H|`` the candidate's effect makes to a model
    FRF value over the band, values more than 60 dB below their FRF's peak taken at that
    depth (``CHANGE_FLOOR``); 0 for none. Below ``NEGLIGIBLE_CHANGE`` the effect is
    negligible whatever the data's noise."""
    if cand.location is None:
        return 0.0
    H = search.nominal.H
    ref = np.maximum(np.abs(H), CHANGE_FLOOR * np.abs(H).max(axis=0, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        change = np.abs(candidate_frf(search, cand) - H) / ref
    return float(np.nanmax(change, initial=0.0))


def candidate_frf(search: SearchResult, cand: Candidate) -> np.ndarray:
    """Model accelerance with the candidate's effect, (n_freq, n_out, n_in), by Sherman-Morrison
    (or its own modes' damping, ``cand.own_modes``)."""
    nom = search.nominal
    if cand.location is None:
        return nom.H.copy()
    if cand.own_modes is not None:
        return cand.own_modes.H.copy()
    loc, j = candidate_location(search, cand)
    p, q = loc.index[j]
    if q < 0:
        g_o, g_i = nom.G_out[:, :, p], nom.G_in[:, p, :]
    else:
        g_o = nom.G_out[:, :, p] - nom.G_out[:, :, q]
        g_i = nom.G_in[:, p, :] - nom.G_in[:, q, :]
    a = effect_a(effect_dynamic_stiffness(cand.effect, nom.omega), loc.g[:, j])
    return nom.H + (a * nom.omega**2)[:, None, None] * g_o[:, :, None] * g_i[:, None, :]
