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
whose prediction reproduces the measured FRFs better, and says so with both gaps. Better is
by the median over the values of ``|ln(model / measured)|``
(:func:`ssid.correlate_frf.frf_gap_median`): values the noise dominates (antiresonances,
far transfer FRFs under a noise floor) have large log ratios either way, and by the RMS they
decided. With 1 % noise and a floor of 1e-4 of the largest value, the RMS gave the reactions
to a model of the structure on its stand on 24 of 24 seeded chain cases; the median on none,
and to the substructure model on all 24, with the variances stated or not.

A load cell whose sensitivity is far off (entered in mV/kN for mV/N: it reads 1000 times the
force) makes the substructure model loaded by the reactions as measured worse than not loaded
at all, and ``auto`` would take it for the structure on its stand. So one real factor per
load cell is fitted (the prediction is linear in them); a factor within 20 % of a unit slip
(``UNIT_SLIPS``: kN for N, g, the pound-force, a sign) is taken as that slip, and when the
reactions divided by the factors halve the gap (``CLEAR_WIN``), they are applied so
corrected and the choice names each load cell and its factor. Every cell off is also what a
model of the structure on its stand fits (factors near 0: the reactions are internal forces
there), so then each must be a unit slip.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .correlate_frf import frf_gap_median
from .errors import InputError
from .frf import AppliedLoads, FRFData, accelerance_from_model, applied_loads

__all__ = ["REACTION_CHOICES", "ModelParts", "ReactionChoice", "choose_reactions", "fit_load_cell_factors",
           "model_frf_under_loads", "model_parts", "weights_with_reaction_noise"]

#: ``reactions=`` values: decide from the data, apply them, or leave them out.
REACTION_CHOICES = ("auto", "apply", "ignore")

#: Modal damping ratio given a model without C for the choice and the reactions' noise only
#: (the two hypotheses differ by far more than any damping does).
CHOICE_ZETA = 0.02

#: A load cell whose fitted factor lies in this range reads its force as measured (its small
#: gain errors are the calibration check's, ``ssid.discrepancy.calibration``).
AS_MEASURED = (0.5, 1.5)

#: Factors a sensitivity entered in the wrong unit gives a load cell: kN for N, kgf (g) or
#: lbf for N and their inverses, either sign (a cell also mounted reversed). No two lie within
#: a factor 2 of each other, so the snap below cannot pick the wrong one.
UNIT_SLIPS = np.array([sign * u for sign in (1, -1)
                       for u in (1.0, 1e3, 1e-3, 9.80665, 1 / 9.80665, 4.4482216, 1 / 4.4482216)])
#: A way of applying the reactions wins clearly when its gap is below this fraction of the
#: others'. The right one wins by a factor 4 or more on the seeded chain cases (1 and 5 %
#: noise). Reactions divided by the load cells' fitted factors must win so: a factor near 0,
#: which a model holding the reactions itself fits, is otherwise taken for a slip (x 1000)
#: by a hair.
CLEAR_WIN = 0.5
#: A fitted factor within this relative distance of a unit slip is taken to be that slip. An
#: effect the model lacks biases the fit: 948 for 1000 beside a hidden 0.32 kg mass (bench
#: seed 10009), 0.108 for 1/9.81, 943 for 1000 fitted to two cells at once. No two slips lie
#: within this distance of one value.
UNIT_SLIP_RTOL = 0.2


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
        Median log-ratio gap (:func:`ssid.correlate_frf.frf_gap_median`) of the model's
        prediction each way, where both were computed (``auto``).
    text : str
        One line for the engineer; empty when the file has no reactions.
    load_cell_factor : dict
        Reaction DOF -> how many times the force its load cell read, for the load cells whose
        reactions are applied divided by it (``auto`` only; empty: every reaction as measured).
    unclear : bool
        ``auto`` chose by a gap less than ``1 / CLEAR_WIN`` times the other's: the reactions
        as measured hardly change the prediction (a load cell's sensitivity far off, or data
        too noisy to tell).
    """

    loads: AppliedLoads | None
    reactions: list[str]
    how: str
    gap_applied: float | None = None
    gap_ignored: float | None = None
    text: str = ""
    load_cell_factor: dict[str, float] = field(default_factory=dict)
    unclear: bool = False

    @property
    def applied(self) -> bool:
        return self.loads is not None

    @property
    def to_check(self) -> bool:
        """The engineer should check the load cells: a factor was taken, or the choice was unclear."""
        return bool(self.load_cell_factor) or self.unclear

    def corrected(self, frf: FRFData) -> FRFData:
        """``frf`` with each of ``load_cell_factor``'s reactions divided by its factor."""
        return _reactions_scaled(frf, {r: 1.0 / f for r, f in self.load_cell_factor.items()})

    def to_json_dict(self) -> dict:
        return {"in_file": list(self.reactions), "applied": self.applied, "choice": self.how,
                "gap_applied": self.gap_applied, "gap_ignored": self.gap_ignored, "text": self.text,
                "load_cell_factor": dict(self.load_cell_factor), "unclear": self.unclear}


def _reactions_scaled(frf: FRFData, scale: dict[str, float]) -> FRFData:
    """``frf`` with the reactions at the DOFs of ``scale`` multiplied by it (variances by its square)."""
    if not scale:
        return frf
    R = np.array(frf.H_reaction, dtype=complex)
    var = None if frf.H_reaction_var is None else np.array(frf.H_reaction_var, dtype=float)
    for r, lbl in enumerate(frf.reactions):
        if lbl in scale:
            R[:, r, :] *= scale[lbl]
            if var is not None:
                var[:, r, :] *= scale[lbl] ** 2
    return dataclasses.replace(frf, H_reaction=R, H_reaction_var=var)


def _load_cell_factors_off(H: np.ndarray, parts: ModelParts, valid: np.ndarray,
                           react: list[str]) -> tuple[dict[str, float], dict[str, float]]:
    """The load cells taken to read their force a factor off: (reaction DOF -> factor taken,
    reaction DOF -> factor fitted); empty when none is.

    Factors are fitted per load cell (:func:`fit_load_cell_factors`); those outside
    ``AS_MEASURED`` are off, each taken as the unit slip it is near (``_unit_slip``). Every
    load cell off is also what a model holding the reactions itself gives (factors near 0),
    so then they are taken only if each is a unit slip (one wrong unit entered for all cells).
    """
    c = fit_load_cell_factors(H, parts, valid)
    lo, hi = AS_MEASURED
    fitted = {lbl: 1.0 / float(x) for lbl, x in zip(react, c) if not lo <= x <= hi and x != 0}
    slip = {lbl: _unit_slip(f) for lbl, f in fitted.items()}
    if len(fitted) == len(react) and None in slip.values():
        return {}, {}
    return {lbl: fitted[lbl] if s is None else s for lbl, s in slip.items()}, fitted


def _unit_slip(factor: float) -> float | None:
    """The unit slip (``UNIT_SLIPS``) within ``UNIT_SLIP_RTOL`` of ``factor``; None if none is.

    The fit's factor carries the nominal model's errors and the noise (0.2-1.2 % off a factor
    1000 on the stand cases); dividing a held DOF's large reaction by a factor that much off
    leaves a coherent error the search then explains by a spring there. A sensitivity
    entered in the wrong unit is off by one of a few exact factors.
    """
    rel = np.abs(UNIT_SLIPS / factor - 1.0)
    k = int(np.argmin(rel))
    return float(UNIT_SLIPS[k]) if rel[k] <= UNIT_SLIP_RTOL else None


def fit_load_cell_factors(H: np.ndarray, parts: ModelParts, valid: np.ndarray) -> np.ndarray:
    """Real factors ``c_r`` (n_react,) with which the reactions best load the model, in relative terms.

    The prediction ``parts.total(c)`` is linear in ``c``; each value of the measured ``H``
    (n_freq, n_out, n_in) is weighted by ``1/|H|`` as the log-ratio gap weighs it. ``c_r =
    1/gamma_r`` when load cell ``r`` read ``gamma_r`` times its force; about 0 when the model
    holds the reactions itself (the structure on its stand).
    """
    w = np.where(valid, 1.0 / np.maximum(np.abs(H), 1e-300), 0.0)
    A = np.stack([(w * h).ravel() for h in parts.H_reactions], axis=1)
    b = (w * np.where(valid, H - parts.H_inputs, 0)).ravel()
    c, *_ = np.linalg.lstsq(np.concatenate([A.real, A.imag]), np.concatenate([b.real, b.imag]), rcond=None)
    return c


def model_frf_under_loads(M: np.ndarray, C: np.ndarray | None, K: np.ndarray, dofs: list[str],
                          frf: FRFData, loads: AppliedLoads | None) -> np.ndarray:
    """The model's accelerance at ``frf``'s outputs per input, (n_freq, n_out, n_in).

    With ``loads``: under the applied loads (:meth:`ssid.frf.AppliedLoads.predict`); None: a
    unit force at each input's DOF.
    """
    if loads is None:
        return accelerance_from_model(M, C, K, dofs, frf.freq_hz, frf.outputs, frf.inputs).H
    return loads.predict(loads.model_accelerance(M, C, K, dofs, frf.omega, frf.outputs))


@dataclass
class ModelParts:
    """A model's FRFs under the test's loads, split by the measured quantity that carries each part.

    Attributes
    ----------
    H_inputs : (n_freq, n_out, n_in) complex
        The part the unit input forces carry ((m/s^2)/N); the whole FRF off a stand.
    H_reactions : (n_react, n_freq, n_out, n_in) complex
        The part each measured reaction carries (its column of the loads times the model's
        accelerance from its DOF); n_react = 0 when no reactions are applied.
    H_load : (n_freq, n_out, n_load) complex or None
        The model's accelerance from the load DOFs that both come from (None off a stand),
        for the gains' errors-in-variables refit.
    """

    H_inputs: np.ndarray
    H_reactions: np.ndarray
    H_load: np.ndarray | None = None

    @classmethod
    def plain(cls, H_model: np.ndarray) -> ModelParts:
        """No reactions applied: the FRF is the inputs' part alone."""
        H = np.asarray(H_model)
        return cls(H, np.zeros((0, *H.shape), dtype=complex))

    def total(self, reaction_scale: np.ndarray | None = None) -> np.ndarray:
        """The model's FRFs, (n_freq, n_out, n_in); ``reaction_scale`` (n_react,) multiplies
        each reaction's part (None: as measured)."""
        if reaction_scale is None:
            return self.H_inputs + self.H_reactions.sum(axis=0)
        return self.H_inputs + np.einsum("r,rkoj->koj", reaction_scale, self.H_reactions)


def model_parts(M: np.ndarray, C: np.ndarray | None, K: np.ndarray, dofs: list[str], frf: FRFData,
                loads: AppliedLoads | None) -> ModelParts:
    """:class:`ModelParts` of the model ``(M, C, K, dofs)`` for ``frf``'s test.

    ``loads`` None (no reactions, or a model that includes the stand): the plain FRF. Else
    the loads are the unit input forces plus ``frf.H_reaction`` at the reaction DOFs
    (:func:`ssid.frf.applied_loads`), and each of the two is carried through the model's
    accelerance from the load DOFs apart.
    """
    if loads is None or frf.H_reaction is None or not frf.reactions:
        return ModelParts.plain(model_frf_under_loads(M, C, K, dofs, frf, None))
    H_load = loads.model_accelerance(M, C, K, dofs, frf.omega, frf.outputs)  # (n_freq, n_out, n_load)
    rows = [loads.dofs.index(d) for d in frf.inputs]
    H_inputs = H_load[:, :, rows]
    H_reactions = np.stack([H_load[:, :, loads.dofs.index(lbl), None] * frf.H_reaction[:, r, None, :]
                            for r, lbl in enumerate(frf.reactions)])
    return ModelParts(H_inputs, H_reactions, H_load)


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
    # One accelerance from the load DOFs serves the reactions as measured, rescaled and left
    # out (the input forces' part alone is the unloaded model's FRF).
    parts = model_parts(M, Cc, K, dofs, frf, loads)
    g_on = frf_gap_median(frf.H, parts.total(), valid)
    g_off = frf_gap_median(frf.H, parts.H_inputs, valid)
    both = f"median log-ratio gap {g_on:.3g} with them, {g_off:.3g} without"
    close = (". The two ways differ little: the reactions as measured hardly change the prediction "
             "(check the load cells' sensitivity)")
    as_measured = ReactionChoice(loads, react, how, g_on, g_off,
                                 f"measured reactions at {where} applied: the model reproduces the data as the "
                                 f"substructure alone, loaded as the test article was ({both}; --reactions ignore "
                                 "if it includes the stand)")
    factor, fitted = _load_cell_factors_off(frf.H, parts, valid, react)
    if factor:
        scale = np.array([1.0 / factor.get(lbl, 1.0) for lbl in react])
        g_fix = frf_gap_median(frf.H, parts.total(scale), valid)
        # A factor that is no unit slip only where the reactions as measured lose: a gain
        # nearer 1 is the calibration check's, whose estimate models the noise.
        slips = all(_unit_slip(f) is not None for f in factor.values())
        if g_fix < CLEAR_WIN * min(g_on, g_off) and (slips or g_on >= g_off):
            fixed = applied_loads(_reactions_scaled(frf, dict(zip(react, scale))))
            cells = ", ".join(f"{lbl} x {f:.6g} (fitted {fitted[lbl]:.4g})" for lbl, f in factor.items())
            return ReactionChoice(fixed, react, how, g_fix, g_off,
                                  f"measured reactions at {where} applied, with the load cell(s) at {cells} "
                                  f"taken to read that many times the force (divided by it): check their "
                                  f"sensitivity. The model reproduces the data as the substructure alone only "
                                  f"so (median log-ratio gap {g_on:.3g} with the reactions as measured, "
                                  f"{g_fix:.3g} so, {g_off:.3g} without; --reactions ignore if it includes the "
                                  "stand)", factor)
    if g_on < CLEAR_WIN * g_off:
        return as_measured
    clear = g_off < CLEAR_WIN * g_on
    if g_on < g_off:  # by less than CLEAR_WIN
        return dataclasses.replace(as_measured, text=as_measured.text + close, unclear=True)
    return ReactionChoice(None, react, how, g_on, g_off,
                          f"measured reactions at {where} not applied: the model reproduces the data "
                          f"as the structure on its stand ({both}; --reactions apply if it is the "
                          "substructure alone)" + ("" if clear else close), unclear=not clear)


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
