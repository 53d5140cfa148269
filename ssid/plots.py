"""Plots of FRFs and identification results (matplotlib, written to PNG files).

matplotlib is imported inside the functions with the non-interactive Agg backend, so that
importing ``ssid`` never needs a display.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_frf_overlay"]


def plot_frf_overlay(
    path: str,
    freq_hz: np.ndarray,
    curves: dict[str, np.ndarray],
    title: str,
) -> None:
    """Magnitude (log) and phase of one FRF from several sources, overlaid.

    Parameters
    ----------
    path : output PNG file.
    freq_hz : (n_freq,)
    curves : label -> (n_freq,) complex accelerance, (m/s^2)/N.
    title : figure title (say which output and input).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8, 6), height_ratios=[2, 1])
    styles = ["-", "--", ":", "-."]
    for (label, H), ls in zip(curves.items(), styles * 4):
        ax_m.semilogy(freq_hz, np.abs(H), ls, label=label, lw=1.2)
        ax_p.plot(freq_hz, np.degrees(np.angle(H)), ls, lw=1.0)
    ax_m.set_ylabel("|H| [(m/s$^2$)/N]")
    ax_m.legend(loc="best")
    ax_m.grid(True, which="both", alpha=0.3)
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [Hz]")
    ax_p.set_yticks([-180, -90, 0, 90, 180])
    ax_p.grid(True, alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
