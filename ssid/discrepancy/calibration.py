"""Channel gains: is the gap a calibration error rather than a missing physical effect?

A wrong accelerometer sensitivity (a typing error, a sensor calibrated in g and entered in
m/s^2, one mounted upside down) scales every FRF of its output by one real factor; a wrong
force-gauge sensitivity every FRF of its input. No change to M, C, K does that: a mass, a
spring or a damper moves or reshapes resonances, a channel gain moves none. The effects
library cannot describe such a gap, and its best candidate then names a physical change
that is not there. So the workflow also fits one real gain per output and per input to the
nominal model's FRFs,

    H_meas[k, i, j] ~ a_i b_j H_model[k, i, j],

and ranks that model with the effects by the same criterion (:func:`check_channel_gains`):
if the gains explain the data better than any effect, or still pay on top of the effect
added, and some gain is more than ``GAIN_TOLERANCE`` off 1, the gap is the transducers'
before it is the structure's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frf import FRFData
from .effects import Effect
from .search import SearchResult

__all__ = ["ChannelGains", "fit_channel_gains", "check_channel_gains"]

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
        ``n_out + n_in - 1``: the gains' free parameters.
    """

    output_gain: np.ndarray
    input_gain: np.ndarray
    rss: float
    n_parameters: int

    def largest_deviation(self) -> float:
        """``max |ln(a_i b_j)|`` over the FRFs (0.0953 for a gain of 1.1 or 1/1.1); infinite
        when a gain is negative (a reversed channel) or zero."""
        g = self.output_gain[:, None] * self.input_gain[None, :]
        if np.any(g <= 0):
            return float("inf")
        return float(np.max(np.abs(np.log(g))))

    def describe(self, outputs: list[str], inputs: list[str], n_show: int = 3) -> str:
        """The gains farthest from 1 (on a log scale), e.g. ``"output '4+Z' x 1000"``: the
        measured FRFs of that channel over the model's."""
        every = self.output_gain[:, None] * self.input_gain[None, :]
        common = float(np.median(every))
        if np.all(np.abs(every / common - 1) <= COMMON_RTOL):
            # One factor for all: a force gauge (or a common amplifier gain) or the model's
            # overall mass scale; the FRFs alone cannot tell which.
            return (f"every FRF x {common:.4g} (one factor for all channels: a force gauge's "
                    "calibration, or the model's overall mass scale)")
        gains = [("output", lbl, g) for lbl, g in zip(outputs, self.output_gain)]
        if len(inputs) > 1:
            gains += [("input", lbl, g) for lbl, g in zip(inputs, self.input_gain)]
        far = sorted(gains, key=lambda t: -abs(np.log(max(abs(t[2]), 1e-300))) - (t[2] < 0))
        return ", ".join(f"{kind} {lbl!r} x {g:.4g}" for kind, lbl, g in far[:n_show])


def fit_channel_gains(H_meas: np.ndarray, H_model: np.ndarray, W: np.ndarray,
                      iterations: int = 100, rtol: float = 1e-10) -> ChannelGains:
    """Real gains ``a`` (outputs) and ``b`` (inputs) minimising ``sum |W (H_meas - a b H_model)|^2``.

    Alternating least squares: with ``b`` fixed each ``a_i`` is a one-parameter linear fit
    (and vice versa), so each half-step lowers the cost and the pair converges to a
    stationary point; starting from ``a = b = 1`` (the model as it is) it finds the gains
    nearest the nominal calibration, sign errors included. (Written out rather than handed
    to ``scipy.optimize.least_squares``: each half-step is a closed-form ratio of sums over
    the data already in memory, where a general solver would form an (n_values x n_gains)
    Jacobian.)

    Parameters
    ----------
    H_meas, H_model : (n_freq, n_out, n_in) complex
        Measured and modelled accelerances (the model under the test's loads).
    W : (n_freq, n_out, n_in) float
        Weights ``1/sigma``, 0 where a value is not valid.
    iterations, rtol : int, float
        At most ``iterations`` sweeps; stop when the cost falls by less than ``rtol`` of itself.

    Returns
    -------
    ChannelGains
    """
    w2 = np.asarray(W, float) ** 2
    cross = w2 * np.real(np.conj(H_model) * H_meas)  # (n_freq, n_out, n_in)
    power = w2 * np.abs(H_model) ** 2
    n_out, n_in = H_model.shape[1], H_model.shape[2]
    a, b = np.ones(n_out), np.ones(n_in)

    def cost() -> float:
        return float(np.sum(w2 * np.abs(H_meas - a[None, :, None] * b[None, None, :] * H_model) ** 2))

    def fit(num: np.ndarray, den: np.ndarray, keep: np.ndarray) -> np.ndarray:
        # A channel the weights do not see keeps its gain.
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), keep)

    last = cost()
    for _ in range(iterations):
        a = fit(np.einsum("kij,j->i", cross, b), np.einsum("kij,j->i", power, b**2), a)
        b = fit(np.einsum("kij,i->j", cross, a), np.einsum("kij,i->j", power, a**2), b)
        now = cost()
        if last - now <= rtol * max(last, 1e-300):
            last = now
            break
        last = now
    if np.all(b != 0):
        common = float(np.exp(np.mean(np.log(np.abs(b)))))
        a, b = a * common, b / common
    return ChannelGains(a, b, last, n_out + n_in - 1)


def check_channel_gains(search: SearchResult, H: np.ndarray, H_nom: np.ndarray, H_upd: np.ndarray,
                        W: np.ndarray, effects: list[Effect], data: FRFData) -> dict:
    """Channel gains against the effects, by the search's own EBIC; the workflow's
    ``info["calibration"]`` (``docs/discrepancy.md``, section 8).

    Two questions: do gains alone explain the data better than any effect (a calibration
    error and no structural change), and do gains still pay for their parameters on top of
    the effects added (a calibration error beside a real effect, whose parameters were then
    fitted to miscalibrated data)?
    """
    n_eff = sum(e.n_parameters for e in effects)
    alone = fit_channel_gains(H, H_nom, W)
    d_alone = float(search.criterion(alone.rss, alone.n_parameters)) - float(search.best.criterion)
    on_top, d_top, rss_upd = alone, d_alone, search.rss0
    if effects:
        on_top = fit_channel_gains(H, H_upd, W)
        rss_upd = float(np.sum(W**2 * np.abs(H - H_upd) ** 2))
        d_top = float(search.criterion(on_top.rss, n_eff + on_top.n_parameters)
                      - search.criterion(rss_upd, n_eff))
    # Significant is not enough: a few per cent of gain can stand in for a model that is
    # slightly wrong everywhere (GAIN_TOLERANCE); a calibration error must also be large.
    large = np.log1p(GAIN_TOLERANCE)
    explains_better = d_alone < 0 and alone.largest_deviation() > large
    pays_on_top = bool(effects) and d_top < 0 and on_top.largest_deviation() > large
    gains, basis = (alone, "nominal") if explains_better or not pays_on_top else (on_top, "updated")
    gap = float(np.sqrt(gains.rss / search.n_valid))
    gap0 = float(np.sqrt((search.rss0 if basis == "nominal" else rss_upd) / search.n_valid))
    which = gains.describe(data.outputs, data.inputs)
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
        "gap_with_gains": gap,
        "delta_criterion_alone": d_alone,
        "delta_criterion_on_top": d_top,
        "model": "H_meas[k, i, j] ~ a_i b_j H_model[k, i, j], one real gain per output and per "
                 "input (a factor common to all is given to the outputs); H_model the nominal "
                 "model's (basis nominal) or the updated one's (basis updated)",
    }
