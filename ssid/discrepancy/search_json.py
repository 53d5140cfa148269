"""The JSON of a candidate search: the candidates listed, each round's best, the localisation.

Split from ``workflow``: these only read a finished :class:`~ssid.discrepancy.search.SearchResult`.
"""

from __future__ import annotations

import numpy as np

from ..correlate_frf import frf_gap
from .report import GAP_METRIC
from .search import Candidate, SearchResult, candidate_frf

__all__ = ["N_LISTED", "candidate_json", "listed_candidates", "localisation_json", "round_json"]

#: Candidates listed in the JSON besides the best of each effect and ``none``.
N_LISTED = 20


def candidate_json(search: SearchResult, cand: Candidate, H_meas: np.ndarray, valid: np.ndarray) -> dict:
    """One candidate: the contract's keys (those of the result itself), then the search's."""
    return {
        "effect": cand.name,
        "dofs": list(cand.effect.dofs),
        "parameters": dict(cand.effect.parameters),
        "gap_before": search.gap(search.rss0),
        "gap_after": search.gap(cand.rss),
        "gap_metric": GAP_METRIC,
        "gap_after_log_ratio": frf_gap(H_meas, candidate_frf(search, cand), valid),
        "criterion": cand.criterion,
        "delta_criterion": cand.delta_criterion,
        "n_parameters": cand.effect.n_parameters,
        "rss": cand.rss,
        "rejected": cand.rejected,
    }


def listed_candidates(search: SearchResult) -> list[Candidate]:
    """The best N_LISTED candidates, plus the best of every effect (and none), in rank order."""
    keep = list(search.candidates[:N_LISTED])
    for name in {c.name for c in search.candidates}:
        best = search.best_of(name)
        if best is not None and best not in keep:
            keep.append(best)
    return sorted(keep, key=search.candidates.index)  # the search's order: a validated leader stays first


def localisation_json(search: SearchResult, dofs: list[str], n_top: int = 10) -> dict:
    s, p = search.singles, search.pairs
    tot = max(search.rss0, 1e-300)
    top_s = np.argsort(-s.explained)[:n_top]
    top_p = np.argsort(-p.explained)[:n_top] if p.n else np.zeros(0, int)
    return {
        "measure": "share of the weighted residual RSS_0 that one change of the dynamic "
                   "stiffness at the DOF (or between the pair) can remove, E / RSS_0",
        "dofs": [{"dof": dofs[s.index[j, 0]], "explained_fraction": s.explained[j] / tot} for j in top_s],
        "pairs": [{"dofs": [dofs[p.index[j, 0]], dofs[p.index[j, 1]]],
                   "explained_fraction": p.explained[j] / tot} for j in top_p],
    }


def round_json(search: SearchResult, H, valid, dofs) -> dict:
    best = search.best
    runner = next((c for c in search.candidates[1:] if c.name != best.name or c.effect.dofs != best.effect.dofs), None)
    return {
        "best": {"effect": best.name, "dofs": list(best.effect.dofs), "parameters": best.effect.parameters,
                 "criterion": best.criterion},
        "runner_up": None if runner is None else {
            "effect": runner.name, "dofs": list(runner.effect.dofs),
            "parameters": runner.effect.parameters, "delta_criterion": runner.delta_criterion},
        "none_delta_criterion": search.none().delta_criterion,
        "gap_before": search.gap(search.rss0),
        "gap_best": search.gap(best.rss),
    }
