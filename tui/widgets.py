"""Terminal plots of FRFs for the TUI (``textual-plotext``): magnitude on a log-log grid with
coherence on the right axis, and measured-vs-model overlays.

The log axes are drawn as linear axes of log10 values with labelled ticks: plotext (5.3)
applies its own log scale to the stored data at every build, and Textual builds a widget
at every repaint, so a second repaint took the log of a log (a crash on the first
resize or tab switch).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from time import monotonic

import numpy as np
from textual.clock import Clock
from textual.widgets import ProgressBar
from textual_plotext import PlotextPlot

__all__ = ["FrfPlot", "HoldableClock", "RunProgress", "log_ticks"]


def log_ticks(lo: float, hi: float, max_ticks: int = 6) -> tuple[list[float], list[str]]:
    """Tick positions (log10 units) and labels for a log axis from ``lo`` to ``hi`` (> 0):
    1-2-5 steps per decade when they fit, else decades."""
    lo, hi = float(lo), float(hi)
    d0, d1 = int(np.floor(np.log10(lo))), int(np.ceil(np.log10(hi)))
    for mantissas in ((1, 2, 5), (1,)):
        vals = [m * 10.0**d for d in range(d0, d1 + 1) for m in mantissas]
        vals = [v for v in vals if lo <= v * (1 + 1e-9) and v <= hi * (1 + 1e-9)]
        if len(vals) <= max_ticks:
            break
    else:
        step = int(np.ceil(len(vals) / max_ticks))
        vals = vals[::step]
    if not vals:  # less than one tick in range: the ends
        vals = [lo, hi]
    return [float(np.log10(v)) for v in vals], [f"{v:g}" for v in vals]


class FrfPlot(PlotextPlot):
    """|H| against frequency (log-log), optionally coherence (0..1, right axis) or overlays."""

    def show_message(self, title: str) -> None:
        plt = self.plt
        plt.clear_data()
        plt.clear_figure()
        plt.title(title)
        self.refresh()

    def show_live(self, title: str, freq_hz: Sequence[float], mag: Sequence[float], coh: Sequence[float]) -> None:
        """The FRF as its lines arrive: |H| (left, log) and coherence (right, linear)."""
        plt = self.plt
        plt.clear_data()
        plt.clear_figure()
        plt.title(title)
        if len(freq_hz) == 0:
            self.refresh()
            return
        f, m = np.asarray(freq_hz, float), np.asarray(mag, float)
        plt.plot(np.log10(f).tolist(), np.log10(m).tolist(), label="|H|", marker="braille", yside="left")
        plt.plot(np.log10(f).tolist(), list(coh), label="coh", marker="dot", yside="right", color="green")
        plt.ylim(0, 1.05, yside="right")
        self._log_axes(f, m)
        self.refresh()

    def _log_axes(self, f: np.ndarray, m: np.ndarray) -> None:
        plt = self.plt
        if f.size:
            plt.xticks(*log_ticks(f.min(), f.max()))
        if m.size:
            plt.yticks(*log_ticks(m.min(), m.max(), max_ticks=4), yside="left")
        plt.xlabel("Hz")

    def show_overlay(self, title: str, freq_hz: np.ndarray, curves: list[tuple[str, np.ndarray]]) -> None:
        """Several magnitudes over one frequency axis (NaN / non-positive points left out)."""
        plt = self.plt
        plt.clear_data()
        plt.clear_figure()
        plt.title(title)
        colors = ["white", "red", "cyan", "yellow"]
        f = np.asarray(freq_hz, dtype=float)
        shown = []
        for (label, mag), color in zip(curves, colors, strict=False):
            m = np.asarray(mag, dtype=float)
            ok = np.isfinite(m) & (m > 0)
            if ok.any():
                plt.plot(np.log10(f[ok]).tolist(), np.log10(m[ok]).tolist(), label=label, marker="braille",
                         color=color)
                shown.append(m[ok])
        self._log_axes(f, np.concatenate(shown) if shown else np.zeros(0))
        self.refresh()


class HoldableClock(Clock):
    """A clock that stops while held: its time does not advance between :meth:`hold` and
    :meth:`go`, and the held span never counts."""

    def __init__(self, *, get_time: Callable[[], float] = monotonic) -> None:
        super().__init__(get_time=get_time)
        self._held_at: float | None = None

    @property
    def held(self) -> bool:
        return self._held_at is not None

    def hold(self) -> None:
        if self._held_at is None:
            self._held_at = self._get_time()

    def go(self) -> None:
        if self._held_at is not None:
            self._start_time += self._get_time() - self._held_at  # the held span is skipped
            self._held_at = None

    def reset(self) -> None:
        super().reset()
        self._held_at = None

    @property
    def time(self) -> float:
        now = self._get_time() if self._held_at is None else self._held_at
        return now - self._start_time


class RunProgress(ProgressBar):
    """The run's progress bar with its ETA, which counts down only while the run measures.

    The bar's ETA extrapolates from its last progress on its own clock, once a second: it
    went on counting down after an abort and through a pause. Its clock is held instead (the
    ETA stays at what remained when the run paused or ended), and a resumed run counts on
    from there, the pause not taken for slow progress.
    """

    def __init__(self, *, total: float | None = None, show_eta: bool = True, id: str | None = None,
                 clock: HoldableClock | None = None) -> None:
        self.run_clock = clock or HoldableClock()
        super().__init__(total=total, show_eta=show_eta, id=id, clock=self.run_clock)

    def hold(self) -> None:
        """Stop the ETA: the run paused or ended."""
        self.run_clock.hold()
        self.update()  # shown now at the held time, not at the next tick (up to 1 s later)

    def go(self) -> None:
        """Count the ETA down again: the run measures."""
        self.run_clock.go()
        self.update()
