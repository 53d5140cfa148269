"""Band processing (report section 5.2): SSID over overlapping narrow bands.

Each band goes through step 1 and the state-space eigenproblem (Eq. 3.12) on its own lines
only, which avoids the ill-conditioning of one broad-band fit. Its roots are then screened by
the report's four criteria:

1. the root's frequency lies outside its band;
2. its damping is negative;
3. its modal phase collinearity is below a threshold (Eq. 5.20);
4. it is not repeated in another band (true roots are found wherever their band overlaps).

The surviving roots, one per physical mode, get their modal scale factors 1/a~_r from
Eq. 3.23 in one of three ways: BP1 (all lines of the band the root was taken from), BP2 (the
lines near the root's resonance only) or BP3 (the lines near all selected resonances, all
roots at once). With as many selected modes as measured DOFs, M, C, K follow as in step 2.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .identify import identify_step1
from .modal import modal_phase_collinearity, root_frequency_damping
from .step1 import Step1Data, step1_data
from .step2 import StateSpaceModes, assemble_mck, modal_scale_factors, state_space_modes

__all__ = [
    "BandRoot",
    "BandResult",
    "overlapping_bands",
    "process_bands",
    "scale_selected_roots",
    "strongest_roots",
    "plot_band_roots",
]


@dataclass
class BandRoot:
    """One oscillatory root of one band's eigenproblem and the verdict of the criteria."""

    band: int
    lam: complex
    theta: np.ndarray  # (2n,) state-space eigenvector [phi; lambda phi]
    freq_hz: float
    zeta: float
    mpc: float
    rejected: str = ""  # "" if kept, else the first criterion that rejected it
    cluster: int = -1  # index of the physical mode it was matched to


@dataclass
class BandResult:
    """Everything band processing found."""

    bands_hz: list[tuple[float, float]]
    roots: list[BandRoot]
    selected: list[BandRoot]
    data: list[Step1Data] = field(default_factory=list)  # per band (weights included)

    @property
    def freq_hz(self) -> np.ndarray:
        return np.array([r.freq_hz for r in self.selected])

    @property
    def zeta(self) -> np.ndarray:
        return np.array([r.zeta for r in self.selected])


def overlapping_bands(f_lo_hz: float, f_hi_hz: float, width_hz: float,
                      overlap: float = 0.5) -> list[tuple[float, float]]:
    """Bands of ``width_hz`` over [f_lo, f_hi], each overlapping the next by ``overlap``.

    Every line must lie in at least two bands for criterion 4 (a true root is found again in
    another band), so the list starts and ends with a part-band clipped at the record's
    edges: with 50 % overlap, ``(f_lo, f_lo + w/2), (f_lo, f_lo + w), (f_lo + w/2, ...)``.
    """
    if width_hz <= 0 or not 0 < overlap < 1:
        raise ValueError("band width must be > 0 and overlap in (0, 1)")
    step = width_hz * (1 - overlap)
    bands = []
    lo = f_lo_hz - step
    while lo < f_hi_hz:
        a, b = max(lo, f_lo_hz), min(lo + width_hz, f_hi_hz)
        if b > a and (not bands or (a, b) != bands[-1]):
            bands.append((a, b))
        if lo + width_hz >= f_hi_hz + step - 1e-12 * width_hz:
            break
        lo += step
    return bands


def process_bands(
    frf: FRFData,
    bands_hz: list[tuple[float, float]],
    *,
    solver: str = "ml",
    mpc_min: float = 0.8,
    repeat_rtol: float = 0.005,
    min_lines: int | None = None,
) -> BandResult:
    """Run step 1 and Eq. 3.12 per band and select the structural roots (criteria 1-4).

    Parameters
    ----------
    frf : FRFData
    bands_hz : list of (lo, hi) in Hz, e.g. from :func:`overlapping_bands`.
    solver : step-1 solver per band (see :func:`ssid.identify.identify_mck`).
    mpc_min : criterion 3 threshold.
    repeat_rtol : criterion 4: two roots from different bands are the same mode when their
        frequencies agree within this fraction (and their damping within a factor 2).
    min_lines : bands with fewer valid lines are skipped (default: enough real equations for
        the step-1 unknowns per DOF).

    Returns
    -------
    BandResult; ``selected`` holds one root per physical mode, ascending in frequency.
    """
    n = frf.n_out
    p = 2 * n + frf.n_in + frf.n_react
    need = min_lines if min_lines is not None else int(np.ceil(p / (2 * frf.n_in))) + 1
    roots: list[BandRoot] = []
    data: list[Step1Data] = []
    for b, (lo, hi) in enumerate(bands_hz):
        sub = frf.band(lo, hi)
        if sub.n_freq < need:
            data.append(None)
            continue
        est, d, _ = identify_step1(sub, solver=solver)
        data.append(d)
        modes = state_space_modes(est.C_hat, est.K_hat)
        m = modes.n_pairs
        wn, zeta = root_frequency_damping(modes.lam[:m])
        mpc = modal_phase_collinearity(modes.theta_x[:, :m])
        for r in range(m):
            f = wn[r] / (2 * np.pi)
            root = BandRoot(b, complex(modes.lam[r]), modes.theta[:, r].copy(), float(f),
                            float(zeta[r]), float(mpc[r]))
            if not lo <= f <= hi:
                root.rejected = "outside band"
            elif zeta[r] < 0:
                root.rejected = "negative damping"
            elif mpc[r] < mpc_min:
                root.rejected = "low MPC"
            roots.append(root)
    _cluster_repeated(roots, repeat_rtol)
    selected = _pick_representatives(roots, bands_hz)
    return BandResult(bands_hz=list(bands_hz), roots=roots, selected=selected, data=data)


def _cluster_repeated(roots: list[BandRoot], rtol: float) -> None:
    """Criterion 4: group surviving roots of different bands that are the same mode."""
    alive = sorted((r for r in roots if not r.rejected), key=lambda r: r.freq_hz)
    clusters: list[list[BandRoot]] = []
    for r in alive:
        for cl in clusters:
            ref = cl[0]
            if (r.band not in {c.band for c in cl}
                    and abs(r.freq_hz - ref.freq_hz) <= rtol * ref.freq_hz
                    and 0.5 <= r.zeta / max(ref.zeta, 1e-12) <= 2.0):
                cl.append(r)
                break
        else:
            clusters.append([r])
    k = 0
    for cl in clusters:
        if len(cl) < 2:
            cl[0].rejected = "not repeated"
            continue
        for r in cl:
            r.cluster = k
        k += 1


def _pick_representatives(roots: list[BandRoot], bands_hz) -> list[BandRoot]:
    """One root per cluster: the one nearest the centre of its band (least edge effect)."""
    best: dict[int, BandRoot] = {}
    for r in roots:
        if r.rejected or r.cluster < 0:
            continue
        lo, hi = bands_hz[r.band]
        dist = abs(r.freq_hz - 0.5 * (lo + hi)) / (hi - lo)
        cur = best.get(r.cluster)
        if cur is None:
            best[r.cluster] = r
        else:
            clo, chi = bands_hz[cur.band]
            if dist < abs(cur.freq_hz - 0.5 * (clo + chi)) / (chi - clo):
                best[r.cluster] = r
    return sorted(best.values(), key=lambda r: r.freq_hz)


def strongest_roots(frf: FRFData, result: BandResult, n_keep: int) -> BandResult:
    """Keep the ``n_keep`` selected roots that contribute most to the measured FRFs.

    A narrow band finds every mode its lines hold, local ones included, so band processing can
    select more modes than there are sensors; the state-space basis of step 2 holds exactly
    one pair per DOF. The contribution of mode r is its peak accelerance,
    ``|1/a~_r| |theta_r|^2 max_j |theta_r^T d_j| omega_r / zeta_r`` (Eq. 3.17 at resonance),
    with the scale factors from a BP3 fit of all selected roots.
    """
    sel = result.selected
    if len(sel) <= n_keep:
        return result
    u, _ = scale_selected_roots(frf, result, "BP3")
    th = np.column_stack([r.theta for r in sel])[: frf.n_out]
    drive = np.abs(th[frf.input_index()]).max(axis=0)
    wn = np.array([2 * np.pi * r.freq_hz for r in sel])
    zeta = np.array([max(r.zeta, 1e-6) for r in sel])
    strength = np.abs(u) * np.sum(np.abs(th) ** 2, axis=0) * drive * wn / zeta
    keep = np.sort(np.argsort(strength)[::-1][:n_keep])
    return replace(result, selected=[sel[i] for i in keep])


def _modes_of(roots: list[BandRoot]) -> StateSpaceModes:
    lam = np.array([r.lam for r in roots])
    theta = np.column_stack([r.theta for r in roots])
    return StateSpaceModes(lam=np.concatenate([lam, lam.conj()]),
                           theta=np.hstack([theta, theta.conj()]), n_pairs=len(roots))


def _near_resonance(d: Step1Data, roots: list[BandRoot], half_widths: float) -> np.ndarray:
    """Lines within ``half_widths`` half-power bandwidths (at least 3 lines) of any root."""
    f = d.omega / (2 * np.pi)
    df = np.median(np.diff(f)) if f.size > 1 else 1.0
    keep = np.zeros(f.size, dtype=bool)
    for r in roots:
        bw = max(half_widths * r.zeta * r.freq_hz, 3 * df)
        keep |= np.abs(f - r.freq_hz) <= bw
    return keep


def _subset(d: Step1Data, lines: np.ndarray) -> Step1Data:
    return replace(d, omega=d.omega[lines], H=d.H[lines], Hr=d.Hr[lines],
                   weight=d.weight[lines], weight_r=d.weight_r[lines], col_ok=d.col_ok[lines])


def scale_selected_roots(
    frf: FRFData,
    result: BandResult,
    method: str = "BP3",
    half_widths: float = 3.0,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """Modal scale factors of the selected roots by BP1, BP2 or BP3, and M, C, K if possible.

    Parameters
    ----------
    frf : the full FRF data (BP3 uses lines from all bands).
    result : from :func:`process_bands`.
    method : "BP1" (all lines of the root's band, with all that band's oscillatory roots as
        companions, so that neighbouring modes are not forced into this one), "BP2" (as BP1
        but only the lines within ``half_widths`` half-power bandwidths of the root), "BP3"
        (all selected roots at once, lines near any selected resonance, from the whole data).

    Returns
    -------
    (u, mck): ``u`` (m,) complex scale factors ``1/a~_r`` of the selected roots and ``mck``
    = (M, C, K) when the number of selected modes equals the number of measured DOFs (the
    state-space basis is then complete), else None.
    """
    sel = result.selected
    if not sel:
        raise IdentificationError("band processing selected no roots")
    n = frf.n_out
    if method == "BP3":
        # Global: one fit over the lines near all selected resonances of the whole record,
        # with the noise weights the bands estimated.
        d_all = step1_data(frf, _weights_on_grid(frf, result))
        lines = _near_resonance(d_all, sel, half_widths)
        u = modal_scale_factors(_subset(d_all, lines), _modes_of(sel))[: len(sel)]
    elif method in ("BP1", "BP2"):
        u = np.empty(len(sel), dtype=complex)
        for i, r in enumerate(sel):
            d = result.data[r.band]
            companions = [c for c in result.roots if c.band == r.band and c.rejected != "outside band"]
            companions = [r] + [c for c in companions if c is not r]
            if method == "BP2":
                d = _subset(d, _near_resonance(d, [r], half_widths))
            u[i] = modal_scale_factors(d, _modes_of(companions))[0]
    else:
        raise ValueError(f"unknown scale-factor method {method!r}; use BP1, BP2 or BP3")
    mck = None
    if len(sel) == n:
        modes = _modes_of(sel)
        M, C, K, _ = assemble_mck(modes, np.concatenate([u, u.conj()]))
        mck = (M, C, K)
    return u, mck


def _weights_on_grid(frf: FRFData, result: BandResult) -> np.ndarray:
    """Noise weights for the full record assembled from the bands' own estimates."""
    w = np.zeros(frf.H.shape)
    f = frf.freq_hz
    for (lo, hi), d in zip(result.bands_hz, result.data):
        if d is None:
            continue
        sel = (f >= lo) & (f <= hi)
        w[sel] = np.where(w[sel] > 0, np.minimum(w[sel], d.weight), d.weight)
    w[w == 0] = np.median(w[w > 0]) if np.any(w > 0) else 1.0
    return w * frf.valid_mask()


def plot_band_roots(path: str, result: BandResult, true_freq_hz: np.ndarray | None = None) -> None:
    """Stabilisation-style chart: each band's roots against frequency, marked by verdict."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5))
    for b, (lo, hi) in enumerate(result.bands_hz):
        ax.plot([lo, hi], [b, b], color="0.85", lw=6, solid_capstyle="butt", zorder=0)
    marks = {"": ("o", "tab:green", "kept"), "not repeated": ("x", "tab:orange", "not repeated"),
             "low MPC": ("s", "tab:purple", "low MPC"), "negative damping": ("v", "tab:red", "negative damping"),
             "outside band": (".", "0.6", "outside band")}
    seen = set()
    for r in result.roots:
        mk, col, lab = marks[r.rejected]
        ax.scatter(r.freq_hz, r.band, marker=mk, color=col, s=28,
                   label=None if lab in seen else lab, zorder=2)
        seen.add(lab)
    for r in result.selected:
        ax.axvline(r.freq_hz, color="tab:green", lw=0.6, alpha=0.5, zorder=1)
    if true_freq_hz is not None:
        for f in true_freq_hz:
            ax.axvline(f, color="k", lw=0.5, ls=":", zorder=1)
    lo = min(b[0] for b in result.bands_hz)
    hi = max(b[1] for b in result.bands_hz)
    ax.set_xlim(lo, hi)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("band")
    ax.set_title("roots per band (green: selected; dotted: true modes if known)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
