"""Channel gains: is the gap a calibration error rather than a missing physical effect?

A wrong accelerometer sensitivity (a typing error, a sensor calibrated in g and entered in
m/s^2, one mounted upside down) scales every FRF of its output by one real factor; a wrong
force-gauge sensitivity every FRF of its input. No change to M, C, K does that: a mass, a
spring or a damper moves or reshapes resonances, a channel gain moves none. The effects
library cannot describe such a gap, and its best candidate then names a physical change
that is not there. So the workflow also fits one real gain per output and per input to the
nominal model's FRFs,

    H_meas[k, i, j] ~ a_i b_j H_model[k, i, j],

On a test stand the substructure model is loaded by the measured interface reactions
(``ssid.frf.AppliedLoads``), and a load cell's sensitivity scales the part of every FRF
that its reaction carries. Split the model's FRFs into the part the unit input forces
carry, ``H0``, and the part each reaction ``r`` carries, ``H_r`` (both linear in what was
measured); with ``alpha_i``, ``beta_j`` and ``gamma_r`` the accelerometers', force gauges'
and load cells' readings over the truth,

    H_meas[k, i, j] = alpha_i (H0[k, i, j] / beta_j + sum_r H_r[k, i, j] / gamma_r),

since the reactions per unit input, ``R / F``, were measured with both. So one more real
gain per load cell: ``a_i (b_j H0 + sum_r g_r H_r)`` with ``g_r = 1 / gamma_r``. A wrong
load cell otherwise looks much like a spring or damper at its DOF (a load cell reading
25 % high: a grounded spring named there).

The gains are ranked with the effects by the same criterion (:func:`check_channel_gains`):
if the gains explain the data better than any effect, or still pay on top of the effect
added, and some gain is more than ``GAIN_TOLERANCE`` off 1, the gap is the transducers'
before it is the structure's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..frf import FRFData
from ..reaction_loads import ModelParts, model_parts  # re-exported: the gains' fit works on them
from .effects import Effect
from .search import SearchResult
from .stand_noise import StandNoise, refine_channel_gains

__all__ = ["ChannelGains", "ModelParts", "check_channel_gains", "fit_channel_gains", "model_parts",
           "refit_gains_exact"]

#: Gains within this fraction of their median are described as one common factor.
COMMON_RTOL = 0.02
#: A gain is called a calibration error only beyond this fraction off 1. Below it, the gains
#: may be absorbing a model that is slightly wrong everywhere: with a 0.5 % RMS distributed
#: stiffness error that the nominal model lacks, gains on top of the best effect paid for
#: themselves by EBIC in 35 of 40 bench cases with every transducer right, at up to 4.9 % off
#: (``bench/discrepancy_accuracy.py --model-error 0.005``); a calibration sheet's own
#: uncertainty is 1-2 %.
GAIN_TOLERANCE = 0.05


@dataclass
class ChannelGains:
    """One real gain per output and per input that best maps the model's FRFs onto the data.

    Attributes
    ----------
    output_gain : (n_out,) float
        ``a_i``: measured over modelled response at output ``i`` (1: the accelerometer agrees;
        -1: reversed; 1000: a factor 1000 in its sensitivity or units).
    input_gain : (n_in,) float
        ``b_j`` for each input, scaled so that their magnitudes' geometric mean is 1: a factor
        common to every output and every input cannot be told apart (an FRF is a ratio), and
        it is given to the outputs.
    rss : float
        Weighted residual sum of squares left, ``sum |W (H_meas - a b H_model)|^2``.
    n_parameters : int
        ``n_out + n_in + n_react - 1``: the gains' free parameters.
    reaction_gain : (n_react,) float
        ``gamma_r``: each load cell's reading over the force it carried, in the same scale as
        the inputs' gains (1: agrees; empty when no reactions are applied).
    """

    output_gain: np.ndarray
    input_gain: np.ndarray
    rss: float
    n_parameters: int
    reaction_gain: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def largest_deviation(self) -> float:
        """``max |ln(a_i b_j)|`` over the FRFs and ``max |ln gamma_r|`` over the load cells
        (0.0953 for a gain of 1.1 or 1/1.1); infinite when a gain is negative (a reversed
        channel) or zero."""
        g = np.concatenate([(self.output_gain[:, None] * self.input_gain[None, :]).ravel(), self.reaction_gain])
        if np.any(g <= 0):
            return float("inf")
        return float(np.max(np.abs(np.log(g))))

    def describe(self, outputs: list[str], inputs: list[str], n_show: int = 3,
                 reactions: list[str] | None = None) -> str:
        """The gains farthest from 1 (on a log scale), e.g. ``"output '4+Z' x 1000"``: the
        measured FRFs of that channel over the model's; ``"load cell '8+Z' x 1.25"``: that
        load cell's reading over the force."""
        every = self.output_gain[:, None] * self.input_gain[None, :]
        common = float(np.median(every))
        # A force gauge reading beta times the force scales every FRF and every reaction per
        # unit input by 1/beta: the load cells then come out at the common factor too.
        cells_agree = all(min(abs(g - 1), abs(g / common - 1)) <= COMMON_RTOL for g in self.reaction_gain)
        if np.all(np.abs(every / common - 1) <= COMMON_RTOL) and cells_agree:
            # One factor for all: a force gauge (or a common amplifier gain) or the model's
            # overall mass scale; the FRFs alone cannot tell which.
            return (f"every FRF x {common:.4g} (one factor for all channels: a force gauge's "
                    "calibration, or the model's overall mass scale)")
        gains = [("output", lbl, g) for lbl, g in zip(outputs, self.output_gain)]
        if len(inputs) > 1:
            gains += [("input", lbl, g) for lbl, g in zip(inputs, self.input_gain)]
        gains += [("load cell", lbl, g) for lbl, g in zip(reactions or [], self.reaction_gain)]
        far = sorted(gains, key=lambda t: -abs(np.log(max(abs(t[2]), 1e-300))) - (t[2] < 0))
        return ", ".join(f"{kind} {lbl!r} x {g:.4g}" for kind, lbl, g in far[:n_show])


def fit_channel_gains(H_meas: np.ndarray, H_model: np.ndarray | ModelParts, W: np.ndarray,
                      iterations: int = 100, rtol: float = 1e-10) -> ChannelGains:
    """Real gains ``a`` (outputs), ``b`` (inputs) and, on a stand, ``g`` (load cells) minimising
    ``sum |W (H_meas - a_i (b_j H0 + sum_r g_r H_r))|^2`` (the module docstring).

    Alternating least squares: with ``b`` and ``g`` fixed each ``a_i`` is a one-parameter
    linear fit, and with ``a`` fixed ``b`` and ``g`` are a small linear least-squares problem
    (without reactions each ``b_j`` on its own), so each half-step lowers the cost and the
    sweeps converge to a stationary point; starting from all gains 1 (the model as it is) they
    find the gains nearest the nominal calibration, sign errors included. (Written out rather
    than handed to ``scipy.optimize.least_squares``: each half-step is a closed-form solve on
    sums over the data already in memory, where a general solver would form an
    (n_values x n_gains) Jacobian.)

    Parameters
    ----------
    H_meas : (n_freq, n_out, n_in) complex
        Measured accelerances.
    H_model : (n_freq, n_out, n_in) complex or ModelParts
        The model's accelerances under the test's loads; :class:`ModelParts` to fit the load
        cells' gains too.
    W : (n_freq, n_out, n_in) float
        Weights ``1/sigma``, 0 where a value is not valid.
    iterations, rtol : int, float
        At most ``iterations`` sweeps; stop when the cost falls by less than ``rtol`` of itself.

    Returns
    -------
    ChannelGains
    """
    parts = H_model if isinstance(H_model, ModelParts) else ModelParts.plain(H_model)
    H0, Hr = parts.H_inputs, parts.H_reactions
    w2 = np.asarray(W, float) ** 2
    n_out, n_in, n_r = H0.shape[1], H0.shape[2], Hr.shape[0]
    a, b, g = np.ones(n_out), np.ones(n_in), np.ones(n_r)

    def model() -> np.ndarray:
        return b[None, None, :] * H0 + np.einsum("r,rkij->kij", g, Hr)

    def cost() -> float:
        return float(np.sum(w2 * np.abs(H_meas - a[None, :, None] * model()) ** 2))

    def fit(num: np.ndarray, den: np.ndarray, keep: np.ndarray) -> np.ndarray:
        # A channel the weights do not see keeps its gain.
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), keep)

    last = cost()
    for _ in range(iterations):
        P = model()
        a = fit(np.einsum("kij->i", w2 * np.real(np.conj(P) * H_meas)), np.einsum("kij->i", w2 * np.abs(P) ** 2), a)
        aH0 = a[None, :, None] * H0
        if n_r == 0:
            b = fit(np.einsum("kij->j", w2 * np.real(np.conj(aH0) * H_meas)), np.einsum("kij->j", w2 * np.abs(aH0) ** 2), b)
        else:
            # Basis of the (b, g) fit: a_i H0 in input j's column alone, then a_i H_r.
            basis = np.concatenate([np.eye(n_in)[:, None, None, :] * aH0[None], a[None, None, :, None] * Hr])
            weighted = w2[None] * np.conj(basis)
            normal = np.real(np.einsum("pkij,qkij->pq", weighted, basis))
            rhs = np.real(np.einsum("pkij,kij->p", weighted, H_meas))
            x = np.linalg.lstsq(normal, rhs, rcond=None)[0]
            b, g = x[:n_in], x[n_in:]
        now = cost()
        if last - now <= rtol * max(last, 1e-300):
            last = now
            break
        last = now
    if np.all(b != 0):
        common = float(np.exp(np.mean(np.log(np.abs(b)))))
        a, b, g = a * common, b / common, g / common
    with np.errstate(divide="ignore"):
        gamma = np.where(g != 0, 1.0 / np.where(g != 0, g, 1.0), np.inf)
    return ChannelGains(a, b, last, n_out + n_in + n_r - 1, gamma)


def refit_gains_exact(gains: ChannelGains, stand: StandNoise, parts: ModelParts, data: FRFData) -> ChannelGains:
    """``gains`` refitted on the errors-in-variables cost against the model of ``parts``
    (``stand_noise.refine_channel_gains``); their ``rss`` is that cost."""
    a, b, gamma, cost = refine_channel_gains(stand, parts.H_load, data.inputs, list(data.reactions or []),
                                             gains.output_gain, gains.input_gain, gains.reaction_gain)
    return ChannelGains(a, b, cost, gains.n_parameters, gamma)


def check_channel_gains(search: SearchResult, H: np.ndarray, H_nom: np.ndarray | ModelParts,
                        H_upd: np.ndarray | ModelParts, W: np.ndarray, effects: list[Effect],
                        data: FRFData, stand: StandNoise | None = None, next_gap: float | None = None) -> dict:
    """Channel gains against the effects, by the search's own EBIC; the workflow's
    ``info["calibration"]`` (``docs/discrepancy.md``, section 8).

    Two questions: do gains alone explain the data better than any effect (a calibration
    error and no structural change), and do gains still pay for their parameters on top of
    the effects added (a calibration error beside a real effect, whose parameters were then
    fitted to miscalibrated data)? ``H_nom``, ``H_upd``: the nominal and updated models'
    FRFs, as :class:`ModelParts` when the model is loaded by measured reactions (the load
    cells' gains are then fitted too).

    ``stand`` (a test stand, reactions applied): the gains are refitted, and gains and models
    scored, on the errors-in-variables cost instead of the per-value weighted RSS. A gain
    that scales the noise the reactions bring in (an output at a held DOF, a load cell)
    otherwise pays by shrinking that noise: without stated variances, every null stand case
    tried flagged the held DOF's accelerometer at x 0.09-0.14.

    ``next_gap``: the gap with the next effect the round after the effects names (the
    residual's ``next_effect``). Gains that pay on top of the effects are not flagged when
    that effect lowers the gap further than they do: a second effect the one named left out
    is then the likelier cause (a mass and a spring hidden together, one coupling spring
    named: gains 2230 -> 2160 flagged "check the transducers", the next effect -> 871).
    """
    n_eff = sum(e.n_parameters for e in effects)
    alone = fit_channel_gains(H, H_nom, W)
    exact = stand is not None and alone.reaction_gain.size > 0
    if not exact:
        rss_nom, rss_best, k_best = search.rss0, search.best.rss, search.best.effect.n_parameters
    else:
        alone = refit_gains_exact(alone, stand, H_nom, data)
        rss_nom = stand.cost(H_nom.H_load)
        rss_best, k_best = (stand.cost(H_upd.H_load), n_eff) if effects else (rss_nom, 0)
    d_alone = float(search.criterion(alone.rss, alone.n_parameters) - search.criterion(rss_best, k_best))
    on_top, d_top, rss_upd = alone, d_alone, rss_nom
    if effects:
        on_top = fit_channel_gains(H, H_upd, W)
        if not exact:
            H_upd_total = H_upd.total() if isinstance(H_upd, ModelParts) else H_upd
            rss_upd = float(np.sum(W**2 * np.abs(H - H_upd_total) ** 2))
        else:
            on_top = refit_gains_exact(on_top, stand, H_upd, data)
            rss_upd = rss_best
        d_top = float(search.criterion(on_top.rss, n_eff + on_top.n_parameters)
                      - search.criterion(rss_upd, n_eff))
    # Significant is not enough: a few per cent of gain can stand in for a model that is
    # slightly wrong everywhere (GAIN_TOLERANCE); a calibration error must also be large.
    large = np.log1p(GAIN_TOLERANCE)
    explains_better = d_alone < 0 and alone.largest_deviation() > large
    pays_on_top = bool(effects) and d_top < 0 and on_top.largest_deviation() > large
    effect_left = pays_on_top and next_gap is not None and next_gap < search.gap(on_top.rss)
    pays_on_top = pays_on_top and not effect_left
    # The gains reported: against the nominal model when they stand in for the effect, else
    # against the model with the effect added (against the nominal model they would absorb
    # part of it: a load cell at x 0.13 beside a 0.43 kg mass that is named right).
    gains, basis = (alone, "nominal") if explains_better or not effects else (on_top, "updated")
    gap = search.gap(gains.rss)
    gap0 = search.gap(rss_nom if basis == "nominal" else rss_upd)
    reactions = list(data.reactions or []) if gains.reaction_gain.size else []
    which = gains.describe(data.outputs, data.inputs, reactions=reactions)
    cause = "a sensitivity entered wrong, a unit (g for m/s^2, lbf for N) or a reversed sensor?"
    if explains_better:
        text = (f"channel gains explain the data better than any effect of the library (gap {gap0:.3g} "
                f"-> {gap:.3g} with them; measured over model: {which}): {cause} Check the "
                "transducers' calibration before reading the effect named")
    elif pays_on_top:
        text = (f"with {' and '.join(e.name for e in effects)} added, channel gains still explain "
                f"part of the gap (gap {gap0:.3g} -> {gap:.3g} with them; measured over updated model: "
                f"{which}): {cause} The effect was fitted to these data as they are: check the "
                "transducers' calibration")
    elif effect_left:
        text = (f"channel gains would lower the gap to {search.gap(on_top.rss):.3g} on top of "
                f"{' and '.join(e.name for e in effects)}, and the next effect the search names to "
                f"{next_gap:.3g}: a further effect, not a calibration error, is the likelier cause")
    else:
        text = "no channel gain explains the data better than the effect named"
    return {
        "flagged": bool(explains_better or pays_on_top),
        "explains_better": bool(explains_better),
        "pays_on_top_of_effect": bool(pays_on_top),
        "text": text,
        "basis": basis,
        "output_gain": dict(zip(data.outputs, map(float, gains.output_gain))),
        "input_gain": dict(zip(data.inputs, map(float, gains.input_gain))),
        "reaction_gain": dict(zip(reactions, map(float, gains.reaction_gain))),
        "gap_with_gains": gap,
        "delta_criterion_alone": d_alone,
        "delta_criterion_on_top": d_top,
        "scored": "errors in variables (the reactions' noise modelled exactly)" if exact
                  else "per-value weighted residual",
        "model": "H_meas[k, i, j] ~ a_i b_j H_model[k, i, j], one real gain per output and per "
                 "input (a factor common to all is given to the outputs); H_model the nominal "
                 "model's (basis nominal) or the updated one's (basis updated); under measured "
                 "reactions H_meas ~ a_i (b_j H0 + sum_r H_r / gamma_r), H0 and H_r the parts of "
                 "H_model the unit input forces and each reaction carry, gamma_r (reaction_gain) "
                 "the load cell's reading over the force",
    }
