"""Which lines a stepped sine measures, and in which order.

The frequency lines lie on a *grid*: the coarse list of the setup (``n_lines`` linear or
logarithmic between ``f_min_hz`` and ``f_max_hz``) with every interval cut into ``refine``
parts. The sweep picks lines from that grid on the fly, like the step control of an ODE
solver: the step (in grid intervals, at most ``refine``, i.e. one coarse step) shrinks
where the response vector per unit force changes fast and grows again where it does not,
so that consecutive lines differ by about ``max_change`` (relative). When a step jumped
over a sharp change (a resonance between two lines) the interval is filled in afterwards,
recursively, down to single grid steps.

Several shakers ("one line per shaker in turn", as whole sweeps): the first shaker's sweep
chooses the lines; each later shaker measures every line chosen so far and may add lines
where *its* responses change fast; at the end, earlier shakers measure the lines they miss.
Every line of the FRF file therefore has one sub-line per shaker, which the multi-input
solve ``H = X_A X_F^-1`` needs.

The schedule depends only on the results it is given, so replaying the recorded results
of an interrupted run reproduces its decisions exactly (resume).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["frequency_grid", "relative_change", "sweep_plan"]

#: ``measure(pattern, grid_index)`` returns the response vector per unit force, or None
#: when the line was aborted (a limit).
Measure = Callable[[int, int], "np.ndarray | None"]


def frequency_grid(f_min_hz: float, f_max_hz: float, n_lines: int, spacing: str, refine: int) -> np.ndarray:
    """The candidate lines: ``(n_lines - 1) * refine + 1`` frequencies, strictly increasing."""
    n = (n_lines - 1) * refine + 1
    if spacing == "log":
        return np.geomspace(f_min_hz, f_max_hz, n)
    return np.linspace(f_min_hz, f_max_hz, n)


def relative_change(a: np.ndarray, b: np.ndarray) -> float:
    """``|b - a| / max(|a|, |b|)`` over the response vector (complex, per unit force)."""
    den = max(float(np.linalg.norm(a)), float(np.linalg.norm(b)), 1e-300)
    return float(np.linalg.norm(b - a)) / den


class _Sweep:
    def __init__(self, measure: Measure, n_grid: int, refine: int, max_change: float) -> None:
        self.measure, self.n_grid, self.refine, self.ct = measure, n_grid, refine, max_change
        self.done: dict[int, dict[int, np.ndarray | None]] = {}

    def get(self, p: int, k: int) -> np.ndarray | None:
        d = self.done.setdefault(p, {})
        if k not in d:
            d[k] = self.measure(p, k)
        return d[k]

    def change(self, p: int, a: int, b: int) -> float:
        ya, yb = self.done[p].get(a), self.done[p].get(b)
        if ya is None or yb is None:
            return 0.0  # an aborted line says nothing about the shape of the FRF
        return relative_change(ya, yb)

    def fill(self, p: int, a: int, b: int, downward: bool) -> None:
        """Measure lines strictly between measured lines ``a < b`` where the change is large."""
        c = self.change(p, a, b)
        if b - a <= 1 or c <= 2 * self.ct:
            return
        n_sub = min(b - a, max(2, math.ceil(c / self.ct)))
        inner = [int(v) for v in np.unique(np.round(np.linspace(a, b, n_sub + 1)).astype(int)) if a < v < b]
        for k in (reversed(inner) if downward else inner):
            self.get(p, k)
        pts = [a] + inner + [b]
        pairs = list(zip(pts[:-1], pts[1:]))
        for lo, hi in (reversed(pairs) if downward else pairs):
            self.fill(p, lo, hi, downward)

    def first_pattern(self, p: int) -> None:
        """Adaptive sweep upward from the lowest grid line."""
        i, step = 0, self.refine
        self.get(p, 0)
        last = self.n_grid - 1
        while i < last:
            j = min(i + step, last)
            self.get(p, j)
            c = self.change(p, i, j)
            if c > 2 * self.ct and j - i > 1:
                # Jumped over a sharp change: fill in going back down from where we are,
                # so that every step stays small except the one jump back up afterwards.
                self.fill(p, i, j, downward=True)
                c = self.change(p, max(k for k in self.done[p] if k < j), j)
            grow = self.ct / max(c, 1e-12)
            step = int(min(self.refine, max(1, min(2 * step, math.floor(step * grow)))))
            i = j

    def later_pattern(self, p: int, required: list[int]) -> None:
        """Every required line in order; refine where this shaker sees a fast change."""
        prev = None
        for k in required:
            self.get(p, k)
            if prev is not None:
                self.fill(p, prev, k, downward=True)
            prev = k


def sweep_plan(measure: Measure, n_patterns: int, n_grid: int, refine: int, max_change: float
               ) -> dict[int, dict[int, np.ndarray | None]]:
    """Run the whole stepped-sine schedule through ``measure``; results per pattern and line."""
    sw = _Sweep(measure, n_grid, refine, max_change)
    sw.first_pattern(0)
    for p in range(1, n_patterns):
        required = sorted(set().union(*(sw.done[q].keys() for q in range(p))))
        sw.later_pattern(p, required)
    union = sorted(set().union(*(d.keys() for d in sw.done.values())))
    for p in range(n_patterns):
        for k in union:
            if k not in sw.done[p]:
                sw.get(p, k)
    return sw.done
