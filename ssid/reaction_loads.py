"""A model against FRFs measured on a test stand: apply the measured reactions, or not.

FRFs measured with the test article on a stand (report section 3.3) come with the interface
reactions ``H_reaction`` the stand exerted per unit input force. What a model should be
compared with depends on what the model is:

* a model of the **substructure alone** (the analyst's FE model of the payload) responds to
  the test only when it is loaded as the test article was, by the input force *and* the
  measured reactions (:func:`ssid.frf.applied_loads`); without them it is compared with a
  structure it is not (free instead of held);
* a model of the **structure on its stand** (stand included) holds the reactions as
  internal forces: applying them again would count them twice.

The file cannot say which; the data can: the two hypotheses differ at every line below the
stand's modes, far more than a missing effect changes the response. ``auto`` takes the one
whose prediction reproduces the measured FRFs better, and says so with both gaps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .correlate_frf import frf_gap
from .errors import InputError
from .frf import AppliedLoads, FRFData, accelerance_from_model, applied_loads

__all__ = ["REACTION_CHOICES", "ReactionChoice", "choose_reactions", "model_frf_under_loads",
           "weights_with_reaction_noise"]

#: ``reactions=`` values: decide from the data, apply them, or leave them out.
REACTION_CHOICES = ("auto", "apply", "ignore")

#: Modal damping ratio given a model without C for the choice and the reactions' noise only
#: (the two hypotheses differ by far more than any damping does).
CHOICE_ZETA = 0.02


@dataclass(frozen=True)
class ReactionChoice:
    """Whether a model is loaded with a test's measured reactions, and why.

    Attributes
    ----------
    loads : AppliedLoads or None
        The loads to apply (None: a unit force at each input, the reactions left out).
    reactions : list of str
        Reaction DOFs in the file (empty: nothing to choose).
    how : str
        ``auto``, ``apply`` or ``ignore``, as asked.
    gap_applied, gap_ignored : float or None
        RMS log-ratio gap (:func:`ssid.correlate_frf.frf_gap`) of the model's prediction
        each way, where both were computed (``auto``).
    text : str
        One line for the engineer; empty when the file has no reactions.
    """

    loads: AppliedLoads | None
    reactions: list[str]
    how: str
    gap_applied: float | None = None
    gap_ignored: float | None = None
    text: str = ""

    @property
    def applied(self) -> bool:
        return self.loads is not None

    def to_json_dict(self) -> dict:
        return {"in_file": list(self.reactions), "applied": self.applied, "choice": self.how,
                "gap_applied": self.gap_applied, "gap_ignored": self.gap_ignored, "text": self.text}


def model_frf_under_loads(M: np.ndarray, C: np.ndarray | None, K: np.ndarray, dofs: list[str],
                          frf: FRFData, loads: AppliedLoads | None) -> np.ndarray:
    """The model's accelerance at ``frf``'s outputs per input, (n_freq, n_out, n_in).

    With ``loads``: under the applied loads (:meth:`ssid.frf.AppliedLoads.predict`); None: a
    unit force at each input's DOF.
    """
    if loads is None:
        return accelerance_from_model(M, C, K, dofs, frf.freq_hz, frf.outputs, frf.inputs).H
    return loads.predict(loads.model_accelerance(M, C, K, dofs, frf.omega, frf.outputs))


def _modal_c(M: np.ndarray, K: np.ndarray) -> np.ndarray:
    from .modal import modal_damping_matrix

    return modal_damping_matrix(M, K, np.full(M.shape[0], CHOICE_ZETA))


def choose_reactions(M: np.ndarray, C: np.ndarray | None, K: np.ndarray, dofs: list[str],
                     frf: FRFData, how: str = "auto") -> ReactionChoice:
    """Decide whether the model ``(M, C, K, dofs)`` is compared with ``frf`` under its reactions.

    Parameters
    ----------
    M, C, K : (n, n)
        The model; ``C`` None: modal damping of ``CHOICE_ZETA`` for the ``auto`` comparison.
    dofs : list of str
        Its DOF labels, which include ``frf``'s outputs and inputs.
    frf : FRFData
        Measured FRFs, with or without ``H_reaction``.
    how : {"auto", "apply", "ignore"}
        ``apply``: the model is the substructure alone; ``ignore``: it includes the stand;
        ``auto``: the one whose prediction has the smaller gap to the data.

    Raises
    ------
    InputError
        ``how`` unknown, or ``apply`` with a reaction DOF the model lacks.
    """
    if how not in REACTION_CHOICES:
        raise InputError(f"reactions: {how!r} is not one of {', '.join(REACTION_CHOICES)}")
    react = list(frf.reactions or []) if frf.H_reaction is not None else []
    if not react:
        return ReactionChoice(None, [], how)
    where = ", ".join(react)
    missing = [r for r in react if r not in dofs]
    if how == "ignore":
        return ReactionChoice(None, react, how, text=f"measured reactions at {where} not applied "
                              "(--reactions ignore: the model includes the stand)")
    if missing:
        if how == "apply":
            raise InputError(f"the measured reactions cannot be applied: the model has no DOF {missing[0]!r}")
        return ReactionChoice(None, react, how, text=f"measured reactions at {where} not applied: the "
                              f"model has no DOF {missing[0]} (taken for the structure on its stand)")
    loads = applied_loads(frf)
    if how == "apply":
        return ReactionChoice(loads, react, how, text=f"measured reactions at {where} applied "
                              "(--reactions apply: the model is the substructure alone)")
    Cc = _modal_c(M, K) if C is None else C
    valid = frf.valid_mask()
    g_on = frf_gap(frf.H, model_frf_under_loads(M, Cc, K, dofs, frf, loads), valid)
    g_off = frf_gap(frf.H, model_frf_under_loads(M, Cc, K, dofs, frf, None), valid)
    both = f"gap {g_on:.3g} with them, {g_off:.3g} without"
    if g_on < g_off:
        return ReactionChoice(loads, react, how, g_on, g_off,
                              f"measured reactions at {where} applied: the model reproduces the data "
                              f"as the substructure alone, loaded as the test article was ({both}; "
                              "--reactions ignore if it includes the stand)")
    return ReactionChoice(None, react, how, g_on, g_off,
                          f"measured reactions at {where} not applied: the model reproduces the data "
                          f"as the structure on its stand ({both}; --reactions apply if it is the "
                          "substructure alone)")


def weights_with_reaction_noise(W: np.ndarray, M: np.ndarray, C: np.ndarray | None, K: np.ndarray,
                                dofs: list[str], frf: FRFData, loads: AppliedLoads) -> np.ndarray:
    """Noise weights ``1/sigma`` (n_freq, n_out, n_in) whose variance also holds the noise the
    measured reactions carry into the prediction, ``sum_l |H(o, l)|^2 var(T[l, j])`` through
    the model (0 stays 0).

    The two are taken as independent. A test's force-gauge noise and settling transient are
    common to its accelerances and reactions and cancel in the substructure's equation, so
    this states more noise than the residual holds where they dominate (docs/discrepancy.md).
    """
    if loads.var is None:
        return W
    Cc = _modal_c(M, K) if C is None else C
    var = loads.predicted_variance(loads.model_accelerance(M, Cc, K, dofs, frf.omega, frf.outputs))
    ok = W > 0
    return np.where(ok, 1.0 / np.sqrt(1.0 / np.where(ok, W, 1.0) ** 2 + var), 0.0)
