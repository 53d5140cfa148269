"""Fit the parameters of every candidate effect at every candidate location.

A location is summarised by ``c``, ``a*`` and ``g`` per line (``ssid.discrepancy.localise``);
an effect with dynamic-stiffness change ``delta(omega; theta)`` there leaves

    cost(theta) = sum_k c_k |a_k(theta) - a*_k|^2,   a_k = delta_k / (1 + delta_k g_k)

on top of ``chi2_0 - E``. This is the exact weighted complex-FRF least-squares cost (no
linearisation): the FRF amplitudes and antiresonances all count, not the frequencies alone,
which is what separates a mass from a negative spring at the same DOF.

Starting values come from the "measured" dynamic-stiffness change
``delta*_k = a*_k / (1 - a*_k g_k)``, to which a one-parameter effect ``theta s(omega)`` is a
*linear* fit: weights ``v_k = c_k |1 - a*_k g_k|^4`` (the delta method's variance of
``delta*``). One-parameter effects are then fitted on a grid of ``theta`` (both signs, four
decades around the start) refined by golden-section search, vectorised over locations. The
attached oscillator (``m``, ``omega_o``, ``zeta_o``) is screened over a grid of tunings, for
each of which the mass enters linearly, and the best few are refined by a trust-region
least-squares solver (``scipy.optimize.least_squares``) on the exact cost. Its damping ratio
is kept above one line spacing over its frequency, ``zeta_o >= d omega / omega_o`` (a
half-power band of at least two lines): a narrower resonance falls between the lines, the data
cannot pin it down, and without the bound a tiny oscillator tuned onto one or two noisy lines
would "explain" them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .effects import oscillator_shape
from .localise import Locations

__all__ = [
    "OneParameterFit",
    "OscillatorFit",
    "effect_a",
    "fit_one_parameter",
    "fit_oscillator",
    "linear_start",
    "min_oscillator_damping",
    "oscillator_screening",
]

#: Decades below and above the start searched for a one-parameter effect, and grid step.
GRID_DECADES = (-2.5, 1.5)
GRID_STEP = 0.1
GOLDEN_ITERATIONS = 40
#: Oscillator tuning grid: natural frequencies over the band widened by this factor ...
OSC_BAND_WIDEN = 1.5
OSC_N_FREQ = 72
#: ... and these damping ratios (raised to the resolvable minimum where needed).
OSC_ZETAS = (0.003, 0.01, 0.03, 0.1, 0.3)
OSC_STARTS = 3
OSC_ZETA_BOUNDS = (1e-4, 0.6)


@dataclass
class OneParameterFit:
    """Fitted value and remaining cost of a one-parameter effect at each location."""

    theta: np.ndarray  # (n_loc,)
    cost: np.ndarray  # (n_loc,) sum c |a - a*|^2 at theta


@dataclass
class OscillatorFit:
    """Fitted oscillator at each location: ``mass_kg``, ``omega_o`` (rad/s), ``zeta_o``."""

    mass_kg: np.ndarray
    omega_o: np.ndarray
    zeta_o: np.ndarray
    cost: np.ndarray

    @classmethod
    def empty(cls, n: int) -> OscillatorFit:
        nan = np.full(n, np.nan)
        return cls(nan.copy(), nan.copy(), nan.copy(), np.full(n, np.inf))

    def parameters(self, j: int) -> dict:
        m, wo, zo = float(self.mass_kg[j]), float(self.omega_o[j]), float(self.zeta_o[j])
        return {"mass_kg": m, "stiffness_n_per_m": m * wo**2, "damping_n_s_per_m": 2 * zo * m * wo}


def effect_a(delta: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``a = delta / (1 + delta g)`` (Sherman-Morrison coefficient); non-finite set to 1e300."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a = delta / (1 + delta * g)
    return np.where(np.isfinite(a), a, 1e300)


def _cost(a: np.ndarray, c: np.ndarray, astar: np.ndarray) -> np.ndarray:
    """``sum_k c |a - a*|^2`` over axis -2 (lines); inf where not finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        val = np.sum(c * np.abs(a - astar) ** 2, axis=-2)
    return np.where(np.isfinite(val), val, np.inf)


def _delta_star_weighted(loc: Locations) -> tuple[np.ndarray, np.ndarray]:
    """``v`` and ``v delta*`` (n_freq, n_loc), computed without dividing by ``1 - a* g``."""
    one = 1 - loc.astar * loc.g
    mag2 = np.abs(one) ** 2
    return loc.c * mag2**2, loc.c * loc.astar * np.conj(one) * mag2


def linear_start(shape: np.ndarray, loc: Locations) -> np.ndarray:
    """Start value of ``theta`` for ``delta = theta shape`` at every location, (n_loc,).

    The weighted linear least-squares fit of ``theta shape`` to ``delta*`` (module docstring).
    """
    v, v_delta = _delta_star_weighted(loc)
    num = np.real(np.conj(shape) @ v_delta)
    den = (np.abs(shape) ** 2) @ v
    with np.errstate(divide="ignore", invalid="ignore"):
        theta = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.where(np.isfinite(theta), theta, 0.0)


def fit_one_parameter(shape: np.ndarray, loc: Locations, chunk: int = 16,
                      nonnegative: bool = False) -> OneParameterFit:
    """Least-squares ``theta`` of ``delta = theta shape(omega)`` at every location.

    Parameters
    ----------
    shape : (n_freq,) complex
        ``delta`` per unit parameter (``ssid.discrepancy.effects.unit_shape``).
    loc : Locations
    nonnegative : bool
        Keep ``theta >= 0`` (a damper: a negative one would feed energy in).

    Returns
    -------
    OneParameterFit; without ``nonnegative``, ``theta`` may be negative (a lost stiffness, a
    model too heavy).
    """
    ref = np.abs(linear_start(shape, loc))
    # A location with no signal at all: search around the scale at which the effect is felt.
    felt = np.median(np.abs(shape[:, None] * loc.g), axis=0) if loc.n else np.zeros(0)
    ref = np.where(ref > 0, ref, 1.0 / np.maximum(felt, 1e-300))
    t = np.arange(GRID_DECADES[0], GRID_DECADES[1] + 1e-9, GRID_STEP)
    grid = np.concatenate([-np.flip(10.0**t), [0.0], 10.0**t])  # relative to ref
    theta = np.zeros(loc.n)
    cost = np.zeros(loc.n)
    for s in range(0, loc.n, chunk):
        sl = slice(s, min(loc.n, s + chunk))
        c, ast, g = loc.c[:, sl], loc.astar[:, sl], loc.g[:, sl]
        th = grid[:, None] * ref[sl][None, :]  # (n_grid, n_chunk)
        vals = _cost(effect_a(th[:, None, :] * shape[None, :, None], g[None]), c[None], ast[None])
        if nonnegative:
            vals[grid < 0] = np.inf
        best = np.argmin(vals, axis=0)
        theta[sl], cost[sl] = _golden(shape, c, ast, g, grid, best, ref[sl], vals)
    return OneParameterFit(theta, cost)


def _golden(shape, c, ast, g, grid, best, ref, vals) -> tuple[np.ndarray, np.ndarray]:
    """Golden-section search in ``log10|theta|`` around each location's best grid point."""
    n_half = (grid.size - 1) // 2
    sign = np.sign(grid[best])
    pos = np.where(best > n_half, best - n_half - 1, n_half - 1 - best)  # index into t
    logs = np.log10(grid[n_half + 1:])
    lo = logs[np.clip(pos - 1, 0, logs.size - 1)]
    hi = logs[np.clip(pos + 1, 0, logs.size - 1)]
    # The outermost grid points are open-ended: let the search run a decade beyond them.
    lo = np.where(pos == 0, lo - 1.0, lo)
    hi = np.where(pos == logs.size - 1, hi + 1.0, hi)

    def f(x):
        th = sign * ref * 10.0**x
        return _cost(effect_a(th[None, :] * shape[:, None], g), c, ast), th

    r = (np.sqrt(5) - 1) / 2
    x1, x2 = hi - r * (hi - lo), lo + r * (hi - lo)
    f1, _ = f(x1)
    f2, _ = f(x2)
    for _ in range(GOLDEN_ITERATIONS):
        left = f1 < f2
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        x2n = np.where(left, x1, lo + r * (hi - lo))
        x1n = np.where(left, hi - r * (hi - lo), x2)
        fn, _ = f(np.where(left, x1n, x2n))
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
        x1, x2 = x1n, x2n
    fm, th = f((x1 + x2) / 2)
    grid_best = vals[best, np.arange(best.size)]
    # Keep the grid point when the refinement did not improve on it (theta = 0 in particular).
    better = (fm < grid_best) & (sign != 0)
    return np.where(better, th, grid[best] * ref), np.where(better, fm, grid_best)


def min_oscillator_damping(omega: np.ndarray, omega_o) -> np.ndarray:
    """Smallest oscillator damping ratio the lines resolve at ``omega_o``: ``d omega / omega_o``.

    ``d omega`` is the line spacing near ``omega_o`` (the band's end spacing outside it).
    """
    w = np.asarray(omega, dtype=float)
    dw = np.gradient(w) if w.size > 1 else np.ones(1)
    wo = np.asarray(omega_o, dtype=float)
    return np.maximum(np.interp(wo, w, dw) / wo, OSC_ZETA_BOUNDS[0])


def _oscillator_grid(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tunings screened: (omega_o, zeta_o) flattened, OSC_N_FREQ x len(OSC_ZETAS)."""
    wo = np.geomspace(omega.min() / OSC_BAND_WIDEN, omega.max() * OSC_BAND_WIDEN, OSC_N_FREQ)
    WO, ZO = np.meshgrid(wo, np.asarray(OSC_ZETAS), indexing="ij")
    return WO.ravel(), np.maximum(ZO, min_oscillator_damping(omega, WO)).ravel()


def _oscillator_starts(S, wo, zo, v: np.ndarray, vd: np.ndarray) -> list[tuple[float, float, float]]:
    """Up to OSC_STARTS (m, omega_o, zeta_o) from the linear screening, with distinct tunings."""
    num = np.real(np.conj(S) @ vd)
    den = (np.abs(S) ** 2) @ v
    with np.errstate(divide="ignore", invalid="ignore"):
        m = num / den
        gain = np.where((den > 0) & (m > 0), num**2 / den, -np.inf)
    starts: list[tuple[float, float, float]] = []
    for i in np.argsort(-gain):
        if not np.isfinite(gain[i]) or len(starts) >= OSC_STARTS:
            break
        if all(abs(np.log(wo[i] / s[1])) > 0.1 for s in starts):
            starts.append((float(m[i]), float(wo[i]), float(zo[i])))
    return starts


def oscillator_screening(omega: np.ndarray, loc: Locations) -> tuple[np.ndarray, tuple]:
    """Approximate cost left by the best-tuned oscillator at every location, (n_loc,).

    The linear screening of the module docstring over the tuning grid (no refinement): the
    delta-space residual ``sum v |m s - delta*|^2`` at the best mass of the best tuning. The
    delta-space weights linearise the exact cost about ``a*``, so this approximates the exact
    ``sum c |a - a*|^2`` where the fit is good and only ranks the others. Also returns what
    :func:`fit_oscillator` needs to start from it.
    """
    wo_g, zo_g = _oscillator_grid(omega)
    S = oscillator_shape(omega, wo_g, zo_g)  # (n_grid, n_freq)
    v, vd = _delta_star_weighted(loc)
    num = np.real(np.conj(S) @ vd)  # (n_grid, n_loc)
    den = (np.abs(S) ** 2) @ v
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where((den > 0) & (num > 0), num**2 / np.where(den > 0, den, 1.0), 0.0)
    # sum v |delta*|^2 = sum c |a*|^2 |1 - a* g|^2, computed without dividing.
    total = np.sum(loc.c * np.abs(loc.astar) ** 2 * np.abs(1 - loc.astar * loc.g) ** 2, axis=0)
    return np.maximum(total - gain.max(axis=0), 0.0), (S, wo_g, zo_g, v, vd)


def _oscillator_jacobian(omega, m, wo, zo, g, sq) -> np.ndarray:
    """d(residual)/d(ln m, ln omega_o, ln zeta_o), real and imaginary parts stacked, (2 n_freq, 3)."""
    r = omega / wo
    N = 1 + 2j * zo * r
    D = N - r**2
    delta = -m * omega**2 * N / D
    dd = np.column_stack([
        delta,
        m * omega**2 * 2 * r**2 * (1 + 1j * zo * r) / D**2,
        m * 2j * omega**2 * r**3 * zo / D**2,
    ])
    with np.errstate(over="ignore", invalid="ignore"):
        J = (sq / (1 + delta * g) ** 2)[:, None] * dd
    J = np.where(np.isfinite(J), J, 0.0)
    return np.vstack([J.real, J.imag])


def fit_oscillator(omega: np.ndarray, loc: Locations, which: np.ndarray, screening=None,
                   resolution: np.ndarray | None = None) -> OscillatorFit:
    """Fit an attached oscillator at the locations ``which`` (indices into ``loc``).

    Parameters ``x = (ln m, ln omega_o, ln zeta_o)``, analytic Jacobian. The damping bound
    ``zeta_o >= zeta_min(omega_o)`` is applied at each start's tuning and checked at the end
    (refitted once with the bound at the final tuning if it moved far enough to break it).
    ``resolution`` (rad/s): the lines that set that bound (default ``omega``; a fit on every
    other line keeps the full set's bound).

    Returns
    -------
    OscillatorFit over all ``loc.n`` locations; those not in ``which`` have NaN and cost inf.
    """
    out = OscillatorFit.empty(loc.n)
    which = np.asarray(which, dtype=int)
    if which.size == 0:
        return out
    S, wo_g, zo_g, v, vd = screening if screening is not None else oscillator_screening(omega, loc)[1]
    res_w = omega if resolution is None else resolution

    def zmin(w):
        return min_oscillator_damping(res_w, w)

    lb_w, ub_w = np.log(omega.min() / 3), np.log(omega.max() * 3)
    z_hi = np.log(OSC_ZETA_BOUNDS[1])
    for j in which:
        ast, g, sq = loc.astar[:, j], loc.g[:, j], np.sqrt(loc.c[:, j])

        def resid(x, ast=ast, g=g, sq=sq):
            d = np.exp(x[0]) * oscillator_shape(omega, np.exp(x[1]), np.exp(x[2]))
            r = sq * (effect_a(d, g) - ast)
            r = np.where(np.isfinite(r), r, 1e150)
            return np.concatenate([r.real, r.imag])

        def jac(x, g=g, sq=sq):
            return _oscillator_jacobian(omega, np.exp(x[0]), np.exp(x[1]), np.exp(x[2]), g, sq)

        best = None
        for m0, w0, z0 in _oscillator_starts(S, wo_g, zo_g, v[:, j], vd[:, j]):
            x = np.array([np.log(m0), float(np.clip(np.log(w0), lb_w + 1e-6, ub_w - 1e-6)), np.log(z0)])
            for _ in range(2):
                z_lo = float(np.log(zmin(np.exp(x[1]))))
                lb = np.array([x[0] - 12, lb_w, z_lo])
                ub = np.array([x[0] + 12, ub_w, max(z_hi, z_lo + 1e-6)])
                res = least_squares(resid, np.clip(x, lb + 1e-9, ub - 1e-9), jac=jac, bounds=(lb, ub),
                                    method="trf", max_nfev=100)
                x = res.x
                if x[2] >= np.log(zmin(np.exp(x[1]))) - 1e-6:
                    break
                x[2] = np.log(zmin(np.exp(x[1])))
            cost = float(np.sum(res.fun**2))
            if x[2] < np.log(zmin(np.exp(x[1]))) - 1e-3:
                continue  # still below the resolvable damping: not a valid fit
            if best is None or cost < best[0]:
                best = (cost, x)
        if best is not None:
            out.cost[j] = best[0]
            out.mass_kg[j], out.omega_o[j], out.zeta_o[j] = np.exp(best[1])
    return out
