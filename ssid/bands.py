"""Band processing (report section 5.2): SSID over overlapping narrow bands, root selection.

Each band goes through step 1 and the state-space eigenproblem (Eq. 3.12) on its own lines
only, which avoids the ill-conditioning of one broad-band fit. Its roots are then screened by
the report's four criteria:

1. the root's frequency lies outside its band;
2. its damping is negative;
3. its modal phase collinearity is below a threshold (Eq. 5.20);
4. it is not repeated in another band (true roots are found wherever their band overlaps).

Checks of ours follow criterion 4, for noise roots that the overlapping bands repeat
because they share lines and noise: a mode that only the nested bands at the record's top
found and the high-edge band does not repeat
(:func:`ssid.band_criteria.reject_top_nested_only`), a mode the lines do not resolve inside
the half-power band of one they do (:func:`ssid.band_criteria.reject_inside_resolved`), and
a weaker mode with a stronger one's shape beside it (:func:`ssid.band_criteria.reject_echoes`). Criteria 1-3
are applied here, as each band's roots are found; criterion 4 and our checks, which compare
roots across bands, are :mod:`ssid.band_criteria`.

The surviving roots, one per physical mode, then get their modal scale factors (BP1, BP2,
BP3, Eq. 3.23) and M, C, K (Eq. 3.26) in :mod:`ssid.band_scaling`. Where the bands lie is
:mod:`ssid.band_edges`. Those two modules' public names are re-exported here, so
``from ssid.bands import scale_selected_roots`` keeps working.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .band_criteria import (
    cluster_repeated,
    phase_seen_by_lines,
    pick_representatives,
    reject_echoes,
    reject_edge_cut_only,
    reject_inside_resolved,
    reject_top_nested_only,
    repeat_tolerance_hz,
    resonance_cut_by_band_edge,
    screen_unresolved,
)
from .band_edges import (
    band_layout,
    band_min_lines,
    default_band_width_hz,
    default_bands,
    distance_to_nearest_line,
    high_edge_band,
    line_spacing_at,
    lines_evenly_spaced,
    low_edge_band,
    min_lines_for_two_bands,
    overlapping_bands,
)
from .band_scaling import (
    fit_scale_factors,
    frf_share,
    residual_runs,
    scale_selected_roots,
    strongest_roots,
)
from .frf import FRFData, require_frequency_dependence, require_response
from .identify import identify_step1, singular_fit_refused
from .modal import modal_phase_collinearity, root_frequency_damping
from .plots_bands import plot_band_roots
from .real_modes import normal_mode_mck
from .step1 import Step1Data
from .step2 import state_space_modes

__all__ = [
    "BandResult",
    "BandRoot",
    "band_min_lines",
    "band_layout",
    "default_band_width_hz",
    "default_bands",
    "distance_to_nearest_line",
    "frf_share",
    "fit_scale_factors",
    "high_edge_band",
    "line_spacing_at",
    "lines_evenly_spaced",
    "low_edge_band",
    "min_lines_for_two_bands",
    "normal_mode_mck",
    "overlapping_bands",
    "plot_band_roots",
    "process_bands",
    "repeat_tolerance_hz",
    "residual_runs",
    "scale_selected_roots",
    "strongest_roots",
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
    #: Whether the nearest line of its band lies within 4 half-widths ``|zeta| f``
    #: (:func:`phase_seen_by_lines`): only then do the lines see its phase and its damping.
    phase_seen: bool = True
    #: False when criterion 3 was not applied: no line sees the phase of its shape
    #: (:func:`phase_seen_by_lines`) and no resolved root crowds it, or an edge of its band
    #: cuts its resonance (``edge_cut``) and another band's estimate must pass it.
    mpc_applied: bool = True
    #: Its half-power band crosses an edge of its band that lies inside the band layout
    #: (:func:`resonance_cut_by_band_edge`).
    edge_cut: bool = False
    #: False when criterion 2 was not applied to a negative damping, for the same reason.
    damping_applied: bool = True
    cluster: int = -1  # index of the physical mode it was matched to
    #: A root of the low-edge band (:func:`ssid.band_edges.low_edge_band`): it may confirm
    #: another band's estimate of an unresolved root (criterion 4), never stand for a mode.
    low_edge: bool = False
    #: A root of the high-edge band (:func:`ssid.band_edges.high_edge_band`): as a low-edge
    #: root, and the third estimate a root found by the nested top bands only must have
    #: (:func:`ssid.band_criteria.reject_top_nested_only`).
    high_edge: bool = False


@dataclass
class BandResult:
    """Everything band processing found."""

    bands_hz: list[tuple[float, float]]  # the bands processed: the layout's, then the edge bands
    roots: list[BandRoot]
    selected: list[BandRoot]
    data: list[Step1Data] = field(default_factory=list)  # per band (weights included)
    low_edge_band: int | None = None  # index of the low-edge band in bands_hz, if one was added
    high_edge_band: int | None = None  # index of the high-edge band in bands_hz, if one was added
    #: Indices (in ``bands_hz``) of the bands not fitted: fewer lines than ``min_lines``.
    skipped: list[int] = field(default_factory=list)
    min_lines: int = 0  # the fewest lines a band needed for step 1
    #: What the analyst must know to read the result: where criterion 4 cannot confirm a root.
    warnings: list[str] = field(default_factory=list)

    @property
    def freq_hz(self) -> np.ndarray:
        return np.array([r.freq_hz for r in self.selected])

    @property
    def n_layout(self) -> int:
        """How many of ``bands_hz`` are the layout's (the edge bands follow them)."""
        edges = [b for b in (self.low_edge_band, self.high_edge_band) if b is not None]
        return min(edges) if edges else len(self.bands_hz)

    @property
    def zeta(self) -> np.ndarray:
        return np.array([r.zeta for r in self.selected])

    def representatives(self) -> list[BandRoot]:
        """One root per physical mode found (criterion 4's clusters), ascending frequency.

        ``selected`` may be a subset of these (:func:`strongest_roots`); BP3 fits them all.
        """
        return pick_representatives(self.roots, self.bands_hz)


@singular_fit_refused()
def process_bands(
    frf: FRFData,
    bands_hz: list[tuple[float, float]],
    *,
    solver: str = "ml",
    mpc_min: float = 0.8,
    repeat_tol: float = 0.125,
    min_lines: int | None = None,
    low_edge: bool = True,
    high_edge: bool = True,
) -> BandResult:
    """Run step 1 and Eq. 3.12 per band and select the structural roots (criteria 1-4).

    Parameters
    ----------
    frf : FRFData
    bands_hz : list of (lo, hi) in Hz, e.g. from :func:`overlapping_bands`.
    solver : step-1 solver per band (see :func:`ssid.identify.identify_mck`).
    mpc_min : criterion 3 threshold.
    repeat_tol : criterion 4: two roots from different bands are the same mode when their
        frequencies agree within this fraction of the width that locates them,
        ``max(2 zeta f, df)`` (Hz), and their damping within a factor 2; see
        :func:`cluster_repeated`. The default 1/8 is 0.5 % of f for a resolved mode with
        2 % damping (the modes of chapter 6).
    min_lines : bands with fewer valid lines are skipped (default: enough real equations for
        the step-1 unknowns per DOF).
    low_edge : add :func:`ssid.band_edges.low_edge_band` after ``bands_hz``: a third
        estimate for roots the lines do not resolve at the record's low edge. Its roots that
        the lines resolve are rejected ("resolved (low-edge band)"): a resolved mode there
        already has the part-band's and the whole band's estimates, and the low-edge band,
        holding every line of both and more modes for the same n DOFs, adds a more biased one
        (on 4 of 8 DOFs measured it confirmed a 1.5 %-off estimate of a 39.7 Hz mode that no
        other band repeated). Its roots never represent a mode.
    high_edge : add :func:`ssid.band_edges.high_edge_band` after those: its roots count as
        the low-edge band's do ("resolved (high-edge band)"), and a mode that only the
        layout's bands ending at the last line found (the top part-band and the band it lies
        in, nested fits that share the part-band's lines and noise) must be found by it too
        (:func:`ssid.band_criteria.reject_top_nested_only`).

    Returns
    -------
    BandResult; ``selected`` holds one root per physical mode, ascending in frequency.
    """
    frf = require_response(frf)
    require_frequency_dependence(frf)
    need = min_lines if min_lines is not None else band_min_lines(frf.n_out, frf.n_in, frf.n_react)
    roots: list[BandRoot] = []
    data: list[Step1Data] = []
    unseen: list[BandRoot] = []  # spared by criterion 2 or 3: the lines do not see them
    extra = low_edge_band(bands_hz, frf.freq_hz) if low_edge else None
    top = high_edge_band(bands_hz, frf.freq_hz) if high_edge else None
    all_bands = list(bands_hz) + [b for b in (extra, top) if b is not None]
    low_index = len(bands_hz) if extra is not None else None
    high_index = len(all_bands) - 1 if top is not None else None
    layout_hz = (min(lo for lo, _ in all_bands), max(hi for _, hi in all_bands))
    for b, (lo, hi) in enumerate(all_bands):
        sub = frf.band(lo, hi)
        if sub.n_freq < need:
            data.append(None)
            continue
        est, d, _ = identify_step1(sub, solver=solver, restart_real_roots=False, low_line_starts=False,
                                   search_above_band=False, model_error_levels=False)
        data.append(d)
        modes = state_space_modes(est.C_hat, est.K_hat)
        m = modes.n_pairs
        wn, zeta = root_frequency_damping(modes.lam[:m])
        mpc = modal_phase_collinearity(modes.theta_x[:, :m])
        for r in range(m):
            f = wn[r] / (2 * np.pi)
            root = BandRoot(b, complex(modes.lam[r]), modes.theta[:, r].copy(), float(f),
                            float(zeta[r]), float(mpc[r]))
            root.phase_seen = phase_seen_by_lines(f, zeta[r], sub.freq_hz)
            root.low_edge, root.high_edge = b == low_index, b == high_index
            root.edge_cut = resonance_cut_by_band_edge(f, zeta[r], (lo, hi), layout_hz)
            if not lo <= f <= hi:
                root.rejected = "outside band"
            elif zeta[r] < 0 or mpc[r] < mpc_min:
                if root.phase_seen and root.edge_cut and zeta[r] >= 0:
                    root.mpc_applied = False  # left to another band's estimate (criterion 4)
                elif root.phase_seen:
                    root.rejected = "negative damping" if zeta[r] < 0 else "low MPC"
                else:
                    root.damping_applied = zeta[r] >= 0
                    root.mpc_applied = mpc[r] >= mpc_min
                    unseen.append(root)
            roots.append(root)
    screen_unresolved(roots, unseen, frf.freq_hz)
    for root in roots:
        # After the screening above, so that the band's resolved roots crowd its unresolved
        # ones as in any band.
        if root.low_edge and root.phase_seen and not root.rejected:
            root.rejected = "resolved (low-edge band)"
        if root.high_edge and root.phase_seen and not root.rejected:
            root.rejected = "resolved (high-edge band)"
    cluster_repeated(roots, repeat_tol, frf.freq_hz)
    reject_edge_cut_only(roots)
    if high_index is not None:
        reject_top_nested_only(roots, all_bands[:len(bands_hz)], high_index, repeat_tol,
                               frf.freq_hz)
    reject_inside_resolved(roots, all_bands, frf.freq_hz)
    reject_echoes(roots, all_bands, data)
    selected = pick_representatives(roots, all_bands)
    skipped = [b for b, d in enumerate(data) if d is None]
    return BandResult(bands_hz=all_bands, roots=roots, selected=selected, data=data,
                      low_edge_band=low_index, high_edge_band=high_index,
                      skipped=skipped, min_lines=need,
                      warnings=_unconfirmable_lines(frf.freq_hz, bands_hz, data, need))


def _unconfirmable_lines(line_freq_hz: np.ndarray, bands_hz: list[tuple[float, float]],
                         data: list, need: int) -> list[str]:
    """A warning where lines lie in fewer than two fitted bands of the layout (``data[b]``
    None: skipped for fewer than ``need`` lines), so that criterion 4 cannot confirm a root
    there: "not repeated" then says nothing about the structure, and 0 modes found does not
    mean there are none. The edge bands are not counted: they confirm unresolved roots only.
    """
    f = np.asarray(line_freq_hz, dtype=float)
    fitted = [(lo, hi) for (lo, hi), d in zip(bands_hz, data) if d is not None]
    cover = sum(((f >= lo) & (f <= hi)).astype(int) for lo, hi in fitted) if fitted else 0 * f
    alone = np.asarray(cover) < 2
    if not alone.any():
        return []
    if len(bands_hz) > 1:
        why = (f"{len(fitted)} of the {len(bands_hz)} bands hold{'s' if len(fitted) == 1 else ''} "
               f"the {need} lines step 1 needs")
        fix = "wider bands"
    else:
        why = (f"the {f.size} lines make one band only, too few for two overlapping bands "
               f"whose part-bands hold the {need} lines step 1 needs")
        fix = "a wider frequency range or more lines"
    if alone.all():
        return [(f"no root can be confirmed as a mode: {why}, so no root can be repeated in "
                 f"another band (criterion 4) and every one is rejected as not repeated; "
                 f"that says nothing of the structure: use {fix}")]
    # Runs of consecutive lines that lie in fewer than two fitted bands.
    edges = np.flatnonzero(np.diff(np.concatenate([[0], alone.astype(int), [0]])))
    runs = ", ".join(f"{f[a]:.6g}-{f[b - 1]:.6g} Hz" for a, b in zip(edges[::2], edges[1::2]))
    return [(f"roots at {runs} cannot be confirmed as modes: those lines lie in fewer than two "
             f"fitted bands ({why}), so criterion 4 cannot repeat a root there; use {fix}")]
