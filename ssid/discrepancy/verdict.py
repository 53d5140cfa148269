"""The discrepancy result's verdict: does one effect close the gap, and what is left?

The sentences ``find_discrepancy`` writes once its rounds are done, from the second round's
search (or none), the effects added and the gap after them, with the noise level's source.
"""

from __future__ import annotations

import numpy as np

from ..io import Model
from ..model_checks import n_unstable_modes
from ..tam import normal_modes
from .effects import Effect
from .search import SearchResult

__all__ = ["GAP_WITHIN_NOISE", "failed_check", "negligible_leader", "negligible_text", "residual_statement",
           "unstable_warning"]

#: Largest gap said to be "within the stated noise". A model as good as the truth has a gap
#: equal to the RMS of the measurement's errors in units of their stated standard
#: deviations, 1 only if those were exact. They are estimates (each line's fit noise and the
#: settling transient left): on the simulated lab's stepped-sine records that RMS against
#: the simulated truth is 0.975 and 0.95 (the demo; the payload at 60-130 Hz, around its close
#: modes).
GAP_WITHIN_NOISE = 1.2


def negligible_leader(checks: list[dict]) -> dict | None:
    """The round's leader if it was turned down as negligible (``ssid.discrepancy.workflow``'s validation, its first check)."""
    if checks and checks[0]["negligible"]:
        c = checks[0]
        return {key: c[key] for key in ("effect", "dofs", "described", "frf_change", "gap_with_it")}
    return None


def negligible_text(negligible: dict | None) -> str:
    if negligible is None:
        return ""
    return (f"; the search's best, {negligible['described']}, would change no model FRF value "
            f"by more than {100 * negligible['frf_change']:.2g} %: negligible, not named")


def residual_statement(second: SearchResult | None, effects: list[Effect], gap_after: float,
                        stated: bool = True, negligible: dict | None = None) -> dict:
    """Does one effect close the gap? The residual and the next-best candidate.

    ``stated``: the noise level is the file's (``H_var``); else it was estimated from the
    data's roughness, which a coarse or adaptive sweep overstates, and the text says so.
    ``negligible``: the deciding round's leader, turned down as negligible
    (:func:`negligible_leader`); the text names it, so that an effect the data show, too
    small to matter, is not mistaken for none.
    """
    nxt = None
    if second is not None:
        b = second.best
        if b.name != "none":  # a candidate named after a negligible one is the news
            negligible = None
        nxt = None if b.name == "none" else {"effect": b.name, "dofs": list(b.effect.dofs),
                                              "parameters": b.effect.parameters,
                                              "criterion_gain_over_none": -second.none().delta_criterion,
                                              "gap_with_it": second.gap(b.rss)}
    closed = nxt is None if (second is not None or not effects) else None
    # One effect, or two (``max_effects=2``: then ``second`` is the third round's search).
    found = " and ".join(e.describe() for e in effects)
    n_found, next_round = ("one effect", "second") if len(effects) < 2 else ("two effects", "third")
    # A negligible leader did pay for its parameters; it is not named for its size.
    nothing_pays = "that matters pays for its parameters" if negligible else "pays for its parameters"
    if closed is None:
        text = f"{found} found; whether it closes the gap was not checked"
    elif (not effects and gap_after > GAP_WITHIN_NOISE and negligible is not None
          and negligible["gap_with_it"] <= GAP_WITHIN_NOISE):
        # The data show the difference beyond their noise, and it is an effect too small to
        # change the model's predictions: nothing is left to look for.
        return {"closed": True, "negligible_effect": negligible, "next_effect": None,
                "text": (f"the data differ from the nominal model by a negligible effect: the "
                         f"search's best, {negligible['described']}, would lower the gap from "
                         f"{gap_after:.3g} to {negligible['gap_with_it']:.3g} (1 = noise level) "
                         f"but change no model FRF value by more than "
                         f"{100 * negligible['frf_change']:.2g} %: not named")}
    elif not effects and gap_after > GAP_WITHIN_NOISE:
        closed = False
        text = (f"no effect of the library {nothing_pays}, yet the gap is {gap_after:.3g} "
                "(1 = noise level): the model differs from the test in a way the library does "
                "not describe")
    elif not effects:
        text = f"the data agree with the nominal model within noise: no effect {nothing_pays}"
    elif closed and gap_after > GAP_WITHIN_NOISE:
        # Nothing more pays, but the gap it leaves is the data's, not noise: as with no effect
        # at all (above), the model differs in a way the library does not describe. Said
        # "closes the gap (gap after 36.6)", the line contradicted itself.
        closed = False
        text = (f"{found} found, and a {next_round} search finds no further effect that "
                f"{nothing_pays}, yet the gap after is {gap_after:.3g} (1 = noise level): the model "
                "differs from the test in a way the library does not describe")
    elif closed:
        text = (f"{found} {'close' if len(effects) > 1 else 'closes'} the gap: a {next_round} search finds "
                f"no further effect (gap after {gap_after:.3g}, 1 = noise level)")
    elif stated and gap_after <= GAP_WITHIN_NOISE:
        # The model now agrees with the test to the noise the file states: that is what a
        # closed gap means to the engineer. The next search ranks each model with its own
        # residual level, so over thousands of values it can still name a pattern that lowers
        # the gap by a fraction of the noise (a 0.3 g oscillator: 0.894 to 0.889); said "does
        # not close the gap", with closed false, a script reading only ``closed`` took the
        # exact effect for a partial one. It is named, for the engineer to judge.
        closed = True
        text = (f"{found} {'close' if len(effects) > 1 else 'closes'} the gap to within the stated noise "
                f"(gap after {gap_after:.3g}, 1 = noise level); the {next_round} search still names "
                f"{nxt['effect']} at {'-'.join(nxt['dofs'])}, which would lower it to {nxt['gap_with_it']:.3g}: "
                "a small effect or a pattern of the measurement's errors, for the engineer to judge")
    else:
        # Within the noise only when the file states none (estimated from the data's roughness,
        # which can be far off): the gap is not called closed on it, and the line says why.
        within = ", within the estimated noise: the file states none" if gap_after <= GAP_WITHIN_NOISE else ""
        # What the next effect would buy tells a pattern of the errors from a missing effect.
        text = (f"{n_found} {'do' if len(effects) > 1 else 'does'} not close the gap (gap after "
                f"{gap_after:.3g}{within}): the {next_round} search names {nxt['effect']} at "
                f"{'-'.join(nxt['dofs'])}, which would lower it to {nxt['gap_with_it']:.3g}")
    return {"closed": closed, "text": text + negligible_text(negligible), "next_effect": nxt,
            "negligible_effect": negligible}


def failed_check(check: dict) -> str:
    """What a leader that failed its checks failed, from its ``cross_validation.checks`` entry."""
    if check.get("negligible"):
        return f"negligible: it changes no model FRF value by more than {100 * check['frf_change']:.2g} %"
    stand = check.get("stand_noise")
    if stand is not None and not stand.get("passed", True):
        return "failed the test with the reactions' noise modelled exactly"
    gain = check.get("heldout_gain")
    if gain is not None and gain <= 0:
        return f"failed the cross-validation: it raised the held-out residual by {-gain:.3g}"
    return "failed its checks"


def _n_unstable(model: Model) -> int | None:
    """Modes of (K, M) with omega^2 clearly below zero; None if M has no normal modes."""
    try:
        lam, _ = normal_modes(model.M, model.K)
    except np.linalg.LinAlgError:  # M not positive definite (massless DOFs): not judged here
        return None
    return n_unstable_modes(lam)


def unstable_warning(nominal: Model, updated: Model, effects: list[Effect]) -> str | None:
    """A warning when the effects make the model unstable (the nominal model was not): the
    updated model is written all the same, as what fits the data, but it is no structure."""
    if not effects or _n_unstable(nominal) != 0:
        return None
    n = _n_unstable(updated)
    if n is None:
        return (f"the updated model's M is not positive definite with {' and '.join(e.describe() for e in effects)}: "
                "it fits the data but is not a physical structure")
    if not n:
        return None
    return (f"the updated model has {n} mode(s) with omega^2 < 0 with {' and '.join(e.describe() for e in effects)} "
            "(K no longer positive semi-definite): it fits the data but is not a stable structure; check the "
            "test setup or the nominal model's stiffness there")
