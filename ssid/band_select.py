"""Model-order / band selection for reduced-order identification (beyond the report).

With more modes in the measured band than the model has DOFs, an n-DOF model fitted over the
whole band chases modes it cannot hold (docs/algorithm.md, "band search").
:func:`identify_mck_band_select` tries bands ``[f_0, f_max / sqrt(2)^k]`` and several solvers
and keeps the physical candidate whose M, C, K best predict every measured line - chosen from
the data alone, never from a true model.
"""

from __future__ import annotations

import numpy as np

from .bands import default_band_width_hz
from .errors import IdentificationError
from .frf import FRFData, require_frequency_dependence
from .identify import identify_mck
from .modal_model import identify_mck_modal
from .noise import data_noise_weights
from .result import SSIDResult, model_accelerance, model_output_error
from .rigid_body import definiteness_problems

__all__ = ["band_ladder", "default_band_width_hz", "identify_mck_band_select", "identify_mck_modal",
           "model_accelerance", "result_problems"]


def result_problems(r: SSIDResult) -> int:
    """How many ways an identified model is not physical (see
    :func:`ssid.written_model.hard_problems`): real roots, negative modal damping, M not positive
    definite, K not positive semi-definite."""
    return int(r.real_roots.size > 0) + int(np.any(r.damping_ratio < 0)) + definiteness_problems(r.M, r.K)


def band_ladder(
    freq_hz: np.ndarray, n_unknowns: int, n_in: int, ratio: float = np.sqrt(2.0),
    max_bands: int = 8, min_equations_per_unknown: float = 4.0,
) -> list[float]:
    """Upper band edges ``f_max, f_max/ratio, f_max/ratio^2, ...`` (Hz) for the band search.

    A band ``[f_0, f_hi]`` is kept while its lines give at least ``min_equations_per_unknown``
    real equations per step-1 unknown of each row of Eq. 3.7 (``2 L n_in >= 4 p``), so that
    every candidate is well over-determined.

    Parameters
    ----------
    freq_hz : (L,) measured lines, Hz, ascending.
    n_unknowns : int
        Step-1 unknowns per row, ``p = 2 n + n_in + n_r`` (Eq. 3.8).
    n_in : int
        Number of inputs (each line gives ``2 n_in`` real equations per row).
    """
    f = np.asarray(freq_hz, dtype=float)
    out: list[float] = []
    hi = float(f[-1])
    while len(out) < max_bands:
        L = int(np.count_nonzero(f <= hi * (1 + 1e-12)))
        if 2 * L * n_in < min_equations_per_unknown * n_unknowns:
            break
        out.append(hi)
        hi /= ratio
    return out


def identify_mck_band_select(
    frf: FRFData,
    *,
    band_max_hz: list[float] | None = None,
    n_refine: int = 2,
    damping: str = "auto",
    candidates: dict | None = None,
    modal: bool = True,
) -> SSIDResult:
    """SSID of a reduced-order model with the band and solver chosen from the data.

    An n-DOF model holds n modes. When the band holds more (or the model is spatially
    truncated and the band's upper modes act as residuals), which n modes it captures, and
    whether it stays physical, depends on the band (the report's section 6.2.3: "the best
    estimation of a given model order is when the input frequency range contains only the
    corresponding number of modes"). This picks that band from the measurements alone:

    1. Candidates: for each upper edge ``f_hi`` of :func:`band_ladder` (or ``band_max_hz``),
       SSID on ``[f_0, f_hi]`` with the report's ``ls``, ``tls`` and ``stls`` step 1 (cheap).
    2. The whole band, and the ``n_refine`` other bands whose best candidate scores best, are
       identified again with the default ``ml`` (costly: O(n^2 p^2) per line). The whole-band
       ``ml`` candidate is :func:`identify_mck`'s default result, so the search can only
       return a model that is physical where that one is not, predicts the data better, or
       is the modal model below. The sub-bands' ``ml`` fits skip the default's search along
       the roots above the band (:func:`ssid.step1_refine.refine_roots_above_band`), which
       would cost most there.
       With ``modal`` (and no reactions), the whole band's band-processed modal model
       (:func:`identify_mck_modal`, solver ``"bands"``) is a candidate too.
    3. Choice: the modal model when it is physical (:func:`result_problems` is 0) and holds
       no residual pair or fitted rigid-body modes: each of its modes was found in two
       overlapping bands, evidence no output error gives (a model that bends its modes to
       absorb those it cannot hold can predict the lines better than the structure itself).
       Otherwise, among the physical candidates (a modal model so completed among them),
       the one with the lowest weighted output error of its M, C, K
       over **all** measured lines, ``sum_kij w_kij^2 |H_kij - H^model_kij|^2`` (Eq. 3.6 solved
       for the accelerance, :func:`model_accelerance`), with ``w = 1/sigma`` the noise
       weights ``ml`` uses (file variances or coherence, else each FRF's roughness). A
       model fitted on a sub-band is judged on how it predicts the lines it did not see.
       When no candidate is physical, the default (whole-band ``ml``) is returned.

    The true model is never used: only the FRFs, their noise levels and physicality.

    Parameters
    ----------
    frf : FRFData
        Accelerances (L, n, n_in) (and optional reactions), as for :func:`identify_mck`.
    band_max_hz : list of float, optional
        Upper band edges to try (default: :func:`band_ladder`, steps of sqrt(2)).
    n_refine : int
        How many of the best sub-bands get the ``ml`` refinement (besides the whole band).
    damping : {"auto", "identified", "modal"}
        As in :func:`identify_mck`.
    modal : bool
        Also try :func:`identify_mck_modal` on the whole band.
    candidates : dict, optional
        Receives every candidate's :class:`SSIDResult` keyed by ``(band_max_hz, solver)``;
        ``candidates[(band_max_hz[0], "ml")]`` is :func:`identify_mck`'s default result.

    Returns
    -------
    SSIDResult
        The chosen candidate; ``info["band_select"]`` lists every candidate's band, solver,
        physicality and output error, and the choice (``choice``, one line; also a warning
        when no candidate was physical).
    """
    # Refused here, not left to every candidate: each would fail alike and the search would
    # end with "no band gave a model" instead of what is wrong with the data.
    require_frequency_dependence(frf)
    w = data_noise_weights(frf)
    n_r = 0 if frf.H_reaction is None else frf.H_reaction.shape[1]
    p = 2 * frf.n_out + frf.n_in + n_r
    his = band_max_hz if band_max_hz is not None else band_ladder(frf.freq_hz, p, frf.n_in)
    if not his:
        raise IdentificationError("too few lines for any band of the search")

    cands: list[tuple[tuple[int, float], float, str, SSIDResult]] = []

    def run(hi: float, solver: str) -> None:
        try:
            if solver == "bands":
                r = identify_mck_modal(frf.band(float(frf.freq_hz[0]), hi))
            else:
                # The search above the band on the whole band's fit only: the sub-bands leave
                # more roots above their edge, so it costs most there, and on the replication
                # bench it changed no band or solver chosen (docs/replication.md).
                r = identify_mck(frf, solver=solver, f_max_hz=hi, damping=damping,
                                 search_above_band=hi == his[0])
            c = model_output_error(frf, r.M, r.C, r.K, w)
        except (IdentificationError, np.linalg.LinAlgError):
            return
        # Physical or not is a gate, not a grade: among non-physical models, one with fewer
        # kinds of problem is not closer to the structure, so the output error decides.
        cands.append(((int(result_problems(r) > 0), c if np.isfinite(c) else np.inf), hi, solver,
                      r))

    for hi in his:
        for solver in ("ls", "tls", "stls"):
            run(hi, solver)
    best_per_band: dict[float, tuple[int, float]] = {}
    for score, hi, _, _ in cands:
        best_per_band[hi] = min(score, best_per_band.get(hi, score))
    # The default (ml on the whole band) always competes, so the search never returns a model
    # that predicts the data worse than the default's, physicality first.
    refine = [his[0]] + [h for h in sorted(best_per_band, key=best_per_band.get) if h != his[0]]
    for hi in refine[: n_refine + 1]:
        run(hi, "ml")
    if modal and frf.H_reaction is None:
        run(his[0], "bands")
    if not cands:
        raise IdentificationError("no band of the search gave a model")
    if candidates is not None:
        candidates.update({(float(h), s): res for _, h, s, res in cands})
    score, hi, solver, r = min(cands, key=lambda c: c[0])
    how = "lowest output error over all lines"
    # A residual pair or rigid-body modes fitted to a mass line were not found in two bands:
    # a model holding them competes on output error.
    modal_physical = [c for c in cands if c[2] == "bands" and not c[0][0]
                      and c[3].info["bands"]["residual_pair_hz"] is None
                      and not c[3].n_rigid_body_modes]
    if modal_physical:
        # Output error cannot tell a model that bends its modes to absorb the ones it cannot
        # hold from one that holds its modes right: the bent one can predict the lines better
        # than the structure itself (docs/algorithm.md). The band-processed model's modes carry
        # evidence the others' lack: each was found again in an overlapping band, with a
        # collinear shape (section 5.2's criteria), and it holds them exactly.
        score, hi, solver, r = modal_physical[0]
        how = "band-processed: every mode it holds was found in two overlapping bands"
    default = [c for c in cands if c[1] == his[0] and c[2] == "ml"]
    if score[0] and default:
        # No physical candidate: a non-physical model that fits the lines better is no
        # evidence of better modes (it may buy the fit with spurious ones), so the default stays.
        score, hi, solver, r = default[0]
    choice = (f"band and solver chosen from the data: {solver} on "
              f"{r.band_hz[0]:g}-{r.band_hz[1]:g} Hz "
              + (f"(physical, {how})" if not score[0] else
                 "(no candidate was physical: the default is kept)"))
    r.info["band_select"] = {
        "band_max_hz": float(hi),
        "solver": solver,
        "choice": choice,
        "candidates": [{"band_max_hz": float(h), "solver": s, "physical": not sc[0],
                        "output_error": sc[1]} for sc, h, s, _ in cands],
    }
    if score[0]:  # a physical choice is the normal outcome, not a warning
        r.warnings.append(choice)
    return r
