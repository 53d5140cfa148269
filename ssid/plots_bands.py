"""The band-processing roots chart (report section 5.2): a stabilisation-style view of every
band's roots and the criterion that kept or rejected each (:mod:`ssid.bands`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # bands.py imports this module to re-export the chart
    from .bands import BandResult

__all__ = ["plot_band_roots"]


def plot_band_roots(path: str, result: BandResult, true_freq_hz: np.ndarray | None = None) -> None:
    """Stabilisation-style chart: each band's roots against frequency, marked by verdict,
    with the selected modes as green lines and ``true_freq_hz`` (Hz; known modes, or an FE
    model's target modes) as dotted ones."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(9, 5))
    skipped = set(result.skipped)
    for b, (lo, hi) in enumerate(result.bands_hz):
        # A band too short for step 1 has no roots: drawn hollow, so that it is not read as
        # a band whose fit found nothing.
        ax.plot([lo, hi], [b, b], color="0.85", lw=6, solid_capstyle="butt", zorder=0,
                ls=":" if b in skipped else "-",
                label="skipped: too few lines for step 1" if b == min(skipped, default=-1) else None)
    marks = {"": ("o", "tab:green", "kept"), "not repeated": ("x", "tab:orange", "not repeated"),
             "low MPC": ("s", "tab:purple", "low MPC"), "negative damping": ("v", "tab:red", "negative damping"),
             "outside band": (".", "0.6", "outside band"),
             "same shape as a stronger mode": ("d", "tab:brown", "same shape as a stronger mode"),
             "inside a resolved mode's half-power band": ("+", "tab:pink",
                                                          "inside a resolved mode's half-power band"),
             "resolved (low-edge band)": (".", "0.3", "resolved (low-edge band: unresolved roots only)"),
             "resolved (high-edge band)": (".", "0.3", "resolved (high-edge band: confirms only)"),
             "not repeated by the high-edge band": ("x", "tab:olive",
                                                    "not repeated by the high-edge band")}
    seen = set()
    ring = "criterion 2 or 3 not applied (no line sees its phase, or a band edge cuts it)"
    for r in result.roots:
        mk, col, lab = marks[r.rejected]
        ax.scatter(r.freq_hz, r.band, marker=mk, color=col, s=28,
                   label=None if lab in seen else lab, zorder=2)
        seen.add(lab)
        if not (r.mpc_applied and r.damping_applied):
            ax.scatter(r.freq_hz, r.band, marker="o", facecolors="none", edgecolors="k", s=90,
                       lw=0.8, label=None if ring in seen else ring, zorder=3)
            seen.add(ring)
    for r in result.selected:
        ax.axvline(r.freq_hz, color="tab:green", lw=0.6, alpha=0.5, zorder=1)
    if true_freq_hz is not None:
        for f in true_freq_hz:
            ax.axvline(f, color="k", lw=0.5, ls=":", zorder=1)
    lo = min(b[0] for b in result.bands_hz)
    hi = max(b[1] for b in result.bands_hz)
    regular = result.bands_hz[: result.n_layout]  # the layout's, without the edge bands
    widths = [b[1] - b[0] for b in regular[1:-1]] or [hi - lo]
    if lo > 0 and max(widths) > 3 * min(widths):
        ax.set_xscale("log")  # bands of equal line count on a log sweep: equal widths on a log axis
    ax.set_xlim(lo, hi)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("band")
    # Bands are numbered: whole ticks, one row per band (a lone band otherwise got -0.04..0.04).
    ax.yaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    ax.set_ylim(-0.5, len(result.bands_hz) - 0.5)
    ax.set_title("roots per band (green: selected; dotted: reference modes, if given)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
