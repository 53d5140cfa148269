"""PNG plots of a correlation: MAC matrix, FRF overlays, frequency errors, CMIF.

matplotlib is imported inside each function with the Agg backend, so importing this module
costs nothing and no display is needed. Each function writes one PNG and returns its path.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from .correlate import modes_at_rest

__all__ = ["plot_cmif", "plot_frequency_errors", "plot_frf_overlay", "plot_mac_matrix"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_mac_matrix(
    mac: np.ndarray,
    path: str | os.PathLike,
    test_freq_hz: Sequence[float] | None = None,
    analysis_freq_hz: Sequence[float] | None = None,
    title: str = "MAC",
) -> str:
    """MAC matrix (test modes in rows, analysis modes in columns) as a colour map, values shown."""
    plt = _pyplot()
    mac = np.asarray(mac, dtype=float)
    n_t, n_a = mac.shape
    fig, ax = plt.subplots(figsize=(1.2 + 0.45 * max(n_a, 4), 1.0 + 0.4 * max(n_t, 4)))
    im = ax.imshow(mac, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    if n_t * n_a <= 900:  # numbers stay legible up to about 30 x 30
        for i in range(n_t):
            for j in range(n_a):
                ax.text(j, i, f"{mac[i, j]:.2f}", ha="center", va="center", fontsize=6,
                        color="black" if mac[i, j] > 0.5 else "white")

    def ticks(freqs, n):
        if freqs is None:
            return [str(k + 1) for k in range(n)]
        rest = modes_at_rest(freqs)
        return [f"{k + 1}\n{_frequency_label(f, r)}" for k, (f, r) in enumerate(zip(freqs, rest))]

    ax.set_xticks(range(n_a), ticks(analysis_freq_hz, n_a), fontsize=6)
    ax.set_yticks(range(n_t), [t.replace("\n", "  ") for t in ticks(test_freq_hz, n_t)], fontsize=6)
    ax.set_xlabel("analysis mode (Hz)")
    ax.set_ylabel("test mode (Hz)")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return os.fspath(path)


def _frequency_label(f_hz: float, at_rest: bool) -> str:
    """A tick's frequency: "0" for a mode at rest (its round-off, "-8.123e-06", overlapped the
    next labels), four significant digits otherwise, without an exponent from 0.01 Hz to 100 kHz."""
    if at_rest:
        return "0"
    return f"{f_hz:.4g}" if 0.01 <= abs(f_hz) < 1e5 else f"{f_hz:.1e}"


def plot_frf_overlay(
    freq_hz: np.ndarray,
    H_test: np.ndarray,
    H_model: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    labels: tuple[str, str] = ("test", "analysis"),
    valid: np.ndarray | None = None,
) -> str:
    """Magnitude (log) and phase (deg) of one FRF from test and model, (n_freq,) each."""
    plt = _pyplot()
    f = np.asarray(freq_hz, dtype=float)
    h = np.asarray(H_test, dtype=complex).copy()
    if valid is not None:
        h[~np.asarray(valid, dtype=bool)] = np.nan
    g = np.asarray(H_model, dtype=complex)
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(7, 5), height_ratios=[2, 1])
    a1.semilogy(f, np.abs(h), "k-", lw=1.0, label=labels[0])
    a1.semilogy(f, np.abs(g), "r--", lw=1.0, label=labels[1])
    a1.set_ylabel("|H| ((m/s^2)/N)")
    a1.grid(True, which="both", alpha=0.3)
    a1.legend(loc="best", fontsize=8)
    a1.set_title(title)
    a2.plot(f, np.degrees(np.angle(h)), "k-", lw=1.0)
    a2.plot(f, np.degrees(np.angle(g)), "r--", lw=1.0)
    a2.set_ylabel("phase (deg)")
    a2.set_yticks([-180, -90, 0, 90, 180])
    a2.set_xlabel("frequency (Hz)")
    a2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return os.fspath(path)


def plot_frequency_errors(
    paired_modes: Sequence[dict], path: str | os.PathLike, title: str = "Frequency error of paired modes"
) -> str:
    """Bar chart of ``freq_error_percent`` of each pair, annotated with its MAC.

    ``paired_modes`` are the JSON pair records (``test_mode``, ``analysis_mode``, ``mac``,
    ``freq_error_percent``, ``rigid``). A pair with an analysis mode at 0 Hz (``rigid``) has no
    percentage error (one against 0 Hz is round-off over round-off, -107 % for two exact
    rigid-body modes, and took the axis): it gets no bar, a grey mark on the zero line labelled
    "rigid" and its error in Hz (``freq_error_hz``), and "R" after its mode numbers.
    """
    plt = _pyplot()
    n = len(paired_modes)
    fig, ax = plt.subplots(figsize=(max(4.0, 0.5 * n + 2), 3.5))
    rigid = np.array([bool(p.get("rigid")) for p in paired_modes], dtype=bool)
    err = np.array([np.nan if r else p["freq_error_percent"] for p, r in zip(paired_modes, rigid)], dtype=float)
    x = np.arange(n)
    elastic = ~rigid & np.isfinite(err)
    ax.bar(x[elastic], err[elastic], color=["tab:red" if abs(e) > 10 else "tab:blue" for e in err[elastic]])
    for k, p in enumerate(paired_modes):
        if rigid[k]:
            ax.plot(k, 0.0, "s", color="0.5", ms=5)
            df = p.get("freq_error_hz")
            ax.annotate(f"rigid {p['mac']:.2f}" + ("" if df is None else f"\n{df:+.2g} Hz"), (k, 0.0),
                        ha="center", va="bottom", fontsize=6, color="0.3", xytext=(0, 4), textcoords="offset points")
        elif elastic[k]:
            ax.annotate(f"{p['mac']:.2f}", (k, err[k]), ha="center", fontsize=6,
                        va="bottom" if err[k] >= 0 else "top")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(x, [f"{p['test_mode']}/{p['analysis_mode']}{' R' if r else ''}"
                      for p, r in zip(paired_modes, rigid)], fontsize=7, rotation=45)
    ax.set_xlabel("test / analysis mode (label: MAC; R: rigid, no % error)" if rigid.any()
                  else "test / analysis mode (label: MAC)")
    ax.set_ylabel("frequency error (%)")
    ax.set_title(title)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return os.fspath(path)


def plot_cmif(
    freq_hz: np.ndarray, sv_test: np.ndarray, sv_model: np.ndarray | None, path: str | os.PathLike,
    peaks_hz: Sequence[float] = (),
) -> str:
    """CMIF curves (singular values of H per line) of test (solid) and model (dashed)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    f = np.asarray(freq_hz, dtype=float)
    for c in range(sv_test.shape[1]):
        ax.semilogy(f, sv_test[:, c], "k-", lw=1.0, alpha=1.0 if c == 0 else 0.5,
                    label="test" if c == 0 else None)
    if sv_model is not None:
        for c in range(sv_model.shape[1]):
            ax.semilogy(f, sv_model[:, c], "r--", lw=1.0, alpha=1.0 if c == 0 else 0.5,
                        label="analysis" if c == 0 else None)
    for p in peaks_hz:
        ax.axvline(p, color="tab:blue", lw=0.6, alpha=0.5)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("singular value ((m/s^2)/N)")
    ax.set_title("CMIF")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return os.fspath(path)
