"""PNG figures of a discrepancy result: FRF overlays, the gap by band, localisation, and the
measured dynamic-stiffness change that names the effect.

matplotlib is imported inside the functions with the Agg backend (no display needed); each
function writes one PNG and returns its path.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .report import DiscrepancyResult

__all__ = [
    "plot_dynamic_stiffness",
    "plot_frf_overlay",
    "plot_gap_by_band",
    "plot_localisation",
    "write_plots",
]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9._+-]", "_", label)


def plot_frf_overlay(result: DiscrepancyResult, i: int, j: int, path: str | os.PathLike) -> str:
    """Measured, nominal and updated accelerance of output ``i``, input ``j``: magnitude and phase."""
    plt = _pyplot()
    a = result.arrays
    f = a["freq_hz"]
    meas = np.where(a["valid"][:, i, j], a["H_meas"][:, i, j], np.nan)
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(7.5, 5.5), height_ratios=[2, 1])
    for H, style, label in ((meas, "k-", "measured"), (a["H_nominal"][:, i, j], "b--", "nominal"),
                            (a["H_updated"][:, i, j], "r-", "updated")):
        ax1.semilogy(f, np.abs(H), style, lw=1.0 if label != "measured" else 1.4, label=label,
                     alpha=0.9 if label != "updated" else 0.8)
        ax2.plot(f, np.degrees(np.angle(H)), style, lw=1.0)
    ax1.set_ylabel("|H| ((m/s^2)/N)")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title(f"output {a['outputs'][i]}, input {a['inputs'][j]}\n{result.effect.describe()}",
                  fontsize=9)
    ax2.set_ylabel("phase (deg)")
    ax2.set_yticks([-180, -90, 0, 90, 180])
    ax2.set_xlabel("frequency (Hz)")
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return os.fspath(path)


def plot_gap_by_band(result: DiscrepancyResult, path: str | os.PathLike) -> str:
    """The gap in each band, nominal and updated model, with the noise level (gap 1) marked."""
    plt = _pyplot()
    rows = result.info["gap_by_band"]
    x = np.arange(len(rows))
    nominal = np.array([r["nominal"] for r in rows], dtype=float)
    updated = np.array([r["updated"] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(7.5, 4.0))
    ax.bar(x - 0.2, nominal, 0.4, label=f"nominal (gap {result.gap_before:.3g})", color="tab:blue")
    ax.bar(x + 0.2, updated, 0.4, label=f"updated (gap {result.gap_after:.3g})", color="tab:red")
    ax.axhline(1.0, color="k", ls=":", lw=1, label="noise level")
    ax.set_yscale("log")
    ax.set_xticks(x, [f"{r['f_lo_hz']:.4g}-\n{r['f_hi_hz']:.4g}" for r in rows], fontsize=7)
    ax.set_xlabel("band (Hz)")
    ax.set_ylabel(f"gap ({result.gap_metric})")
    ax.set_title("Gap between measured and model FRFs by band", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return os.fspath(path)


def plot_localisation(result: DiscrepancyResult, path: str | os.PathLike, n_top: int = 20) -> str:
    """Share of the nominal residual a change at each DOF can remove (best ``n_top`` DOFs)."""
    plt = _pyplot()
    a = result.arrays
    frac = np.asarray(a["explained"], dtype=float)
    order = np.argsort(-frac)[:n_top]
    labels = [a["explained_dofs"][k] for k in order]
    colors = ["tab:red" if lbl in result.effect.dofs else "tab:gray" for lbl in labels]
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    ax.bar(np.arange(order.size), frac[order], color=colors)
    ax.set_xticks(np.arange(order.size), labels, rotation=60, fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("E / RSS_0")
    ax.set_title("Localisation: residual one change at the DOF can remove (red: effect found)",
                 fontsize=9)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return os.fspath(path)


def plot_dynamic_stiffness(result: DiscrepancyResult, path: str | os.PathLike) -> str:
    """Measured dynamic-stiffness change ``delta*`` at the effect's location and the fitted ``delta``.

    A mass shows as ``-omega^2 m`` (real, negative, growing with frequency), a spring as a
    constant, a damper as ``j omega c`` (imaginary part), an oscillator as a resonance.
    """
    plt = _pyplot()
    a = result.arrays
    f = a["freq_hz"]
    ds, df = a["delta_star"], a["delta_fit"]
    where = "-".join(a["delta_dofs"])
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(7.5, 5.0))
    ax1.plot(f, ds.real, "k.", ms=2, label="measured delta* (free per line)")
    # The first round's leader, fitted alone: with two effects it can differ from those named.
    fitted = a.get("delta_effect", result.effect.name)
    ax1.plot(f, df.real, "r-", lw=1.2, label=f"fitted: {fitted}")
    ax2.plot(f, ds.imag, "k.", ms=2)
    ax2.plot(f, df.imag, "r-", lw=1.2)
    for ax, part in ((ax1, "Re"), (ax2, "Im")):
        finite = np.concatenate([ds[np.isfinite(ds)].real if part == "Re" else ds[np.isfinite(ds)].imag,
                                 df.real if part == "Re" else df.imag])
        if finite.size:
            lo, hi = np.percentile(finite, [2, 98])
            pad = 0.2 * (hi - lo) + 1e-12
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"{part} delta (N/m)")
        ax.grid(True, alpha=0.3)
    ax1.legend(fontsize=8)
    first_round = " (first round, one effect)" if len(result.effects) > 1 else ""
    ax1.set_title(f"Dynamic-stiffness change at {where}{first_round}", fontsize=10)
    ax2.set_xlabel("frequency (Hz)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return os.fspath(path)


def _overlay_choice(result: DiscrepancyResult, n_max: int = 4) -> list[tuple[int, int]]:
    """Drive points first, then the FRFs whose gap shrank most."""
    a = result.arrays
    outs, ins = a["outputs"], a["inputs"]
    chosen = [(outs.index(lbl), j) for j, lbl in enumerate(ins)]
    g = result.info["gap_by_frf"]
    shrink = np.nan_to_num(np.asarray(g["nominal"], float) - np.asarray(g["updated"], float), nan=-np.inf)
    for flat in np.argsort(-shrink, axis=None):
        ij = tuple(int(v) for v in np.unravel_index(flat, shrink.shape))
        if ij not in chosen:
            chosen.append(ij)
        if len(chosen) >= n_max + len(ins):
            break
    return chosen[: max(n_max, len(ins))]


def write_plots(result: DiscrepancyResult, directory: str | os.PathLike) -> list[str]:
    """All figures of ``result`` into ``directory`` (created); returns their paths."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = [plot_gap_by_band(result, d / "gap_by_band.png"),
           plot_localisation(result, d / "localisation.png"),
           plot_dynamic_stiffness(result, d / "dynamic_stiffness.png")]
    a = result.arrays
    for i, j in _overlay_choice(result):
        name = f"frf_{_safe(a['outputs'][i])}_{_safe(a['inputs'][j])}.png"
        out.append(plot_frf_overlay(result, i, j, d / name))
    return out
