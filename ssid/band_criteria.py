"""Band processing's root screening: criterion 4 and the checks of ours around it.

The criteria a root meets on its own (1-3: inside its band, positive damping, MPC) are applied
where each band's roots are found (:func:`ssid.bands.process_bands`). The ones here compare
roots across bands or with the lines:

* whether the lines see a root's phase at all (:func:`phase_seen_by_lines`), and whether an
  edge of its band cuts its resonance (:func:`resonance_cut_by_band_edge`): then criteria 2
  and 3 cannot judge it, and another band must;
* criterion 4, a root repeated in another band (:func:`cluster_repeated`, with the tolerance
  :func:`repeat_tolerance_hz`);
* ours, for noise roots the overlapping bands repeat because they share lines and noise:
  a mode only the nested top bands found and the high-edge band does not repeat
  (:func:`reject_top_nested_only`), a mode the lines do not resolve inside the half-power
  band of one they do
  (:func:`reject_inside_resolved`), and a weaker mode with a stronger one's shape beside it
  (:func:`reject_echoes`);
* one root per physical mode (:func:`pick_representatives`).

Each function marks ``BandRoot.rejected`` (or ``cluster``) in place.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .band_edges import distance_to_nearest_line, line_spacing_at
from .band_scaling import frf_share, root_shapes
from .correlate import modal_assurance
from .errors import IdentificationError
from .step1 import Step1Data

if TYPE_CHECKING:  # ssid.bands defines the root record and calls these
    from .bands import BandRoot

__all__ = ["ECHO_HALF_POWER_BANDS", "ECHO_MAC_MIN", "PHASE_SEEN_HALF_WIDTHS", "cluster_repeated",
           "phase_seen_by_lines", "pick_representatives", "reject_echoes", "reject_edge_cut_only",
           "reject_inside_resolved", "reject_top_nested_only", "repeat_tolerance_hz",
           "resonance_cut_by_band_edge",
           "screen_unresolved"]


def repeat_tolerance_hz(freq_hz: np.ndarray, zeta: np.ndarray,
                        nearest_line_hz: float | np.ndarray,
                        tol: float = 0.125) -> np.ndarray:
    """Criterion 4's tolerance (Hz) for roots of frequency ``freq_hz`` and damping ``zeta``.

    A root's frequency is fixed by the lines over the width where its resonance shapes the
    FRF: its half-power band ``2 zeta f`` (Eq. 5.18 for zeta) when the lines resolve it. When
    its nearest line is farther than that, the peak falls between lines and the root is
    located by its skirt at that line, ``d`` away, which sees it as ``r / (f_n - f)``: a
    relative noise ``e`` there moves the estimate by about ``e d``, so two bands' estimates
    of one mode differ by a fraction of ``d``, not of ``2 zeta f``. The tolerance is the
    fraction ``tol`` of ``max(2 zeta f, d)``. On the 16-DOF payload (1-2300 Hz, df = 2.25 Hz)
    the 1.29 Hz suspension mode has ``2 zeta f`` = 0.05 Hz and ``d`` = 0.29 Hz (the 1 Hz
    line); its estimates in the two bands that hold it differ by 1.4 % of f (0.018 Hz, within
    ``d/8`` = 0.036 Hz) with the report's noise. The line spacing ``df`` was used before in
    place of ``d``: ``df/8`` = 0.28 Hz, 22 % of that mode's frequency, paired a 1.29 Hz
    estimate with a 1.53 Hz one (12 sensors, 1-1158 Hz, seed 4) and made a mode of two noise
    roots at 1.04 and 1.15 Hz (seed 28). A lightly damped noise root gets a tighter tolerance
    than under a fixed fraction of f, not a looser one.

    Parameters
    ----------
    freq_hz, zeta : (m,) frequencies (Hz) and damping ratios of the roots.
    nearest_line_hz : distance from each root to the record's nearest line (Hz), scalar or
        (m,) (:func:`distance_to_nearest_line`).
    tol : fraction of the width (1/8: 0.5 % of f for a resolved 2 %-damped mode).

    Returns
    -------
    (m,) tolerance in Hz.
    """
    f = np.asarray(freq_hz, dtype=float)
    z = np.clip(np.asarray(zeta, dtype=float), 0.0, None)
    return tol * np.maximum(2 * z * f, nearest_line_hz)


#: A root's shape phase counts as seen by the lines when the nearest line lies within this
#: many half-power half-widths ``zeta f`` of it (see :func:`phase_seen_by_lines`).
PHASE_SEEN_HALF_WIDTHS = 4.0


def phase_seen_by_lines(freq_hz: float, zeta: float, line_freq_hz: np.ndarray) -> bool:
    """Whether the lines see the phase of a root's resonance, so that criteria 2 (damping
    sign), 3 (MPC) and criterion 4's damping check apply.

    A mode's contribution turns through its phase over its half-power band
    ``[f - zeta f, f + zeta f]``; a line ``d`` away sees it within ``atan(zeta f / d)`` of
    its far-field phase. When every line is more than 4 half-widths away (within 14 deg),
    the lines see only the skirts, whose phase depends neither on the shape's complexity nor
    much on the damping: the noise sets the estimated shape's phase, so its MPC says nothing
    about the mode, and it sets the damping too, sign included. The payload's 1.29 Hz
    suspension mode (``zeta f`` = 0.026 Hz, nearest line 0.29 Hz away: 11 half-widths) has
    MPC 0.07-0.80 under the report's noise in the bands that hold it, 1.0 without, and
    damping from -0.3 % to 8.2 % (2 % true); the lightly damped noise roots that pass
    criteria 1, 2 and 4 in the same records have their nearest line within 2.1 half-widths.
    The 4 lies between. ``zeta`` is taken by magnitude: a root with negative damping is as
    far from being seen as its positive twin.
    """
    d_min = float(distance_to_nearest_line(line_freq_hz, freq_hz)[0])  # 0 with no lines: seen
    return d_min <= PHASE_SEEN_HALF_WIDTHS * abs(zeta) * freq_hz


def resonance_cut_by_band_edge(freq_hz: float, zeta: float, band_hz: tuple[float, float],
                                layout_hz: tuple[float, float]) -> bool:
    """Whether a root's half-power band ``[f - zeta f, f + zeta f]`` crosses an edge of its
    band that lies inside the band layout ``layout_hz`` (at the layout's own ends every band
    holding the root is cut alike, and no other band holds the rest of its resonance).

    Such a band's lines hold part of the resonance only, and the fit sets the shape's phase
    from that part and the band's other modes: on the payload's rotation-dominated 585.5 Hz
    mode (12 sensors, 1-1158 Hz, bands of 96 Hz, the report's noise) the band whose lower
    edge lies 6 Hz below it (half-power half-width 11.7 Hz) gave MPC 0.60-0.80 on the seeds
    where the mode was lost, with frequency and damping within 0.2 % and 0.13 points, while
    the band centred on it gave 0.95-0.99. Criterion 3 is then left to the other band.
    """
    lo, hi = band_hz
    half = abs(zeta) * freq_hz
    return bool((lo > layout_hz[0] and freq_hz - lo < half)
                or (hi < layout_hz[1] and hi - freq_hz < half))


def _resolved_by_lines(root: BandRoot, line_freq_hz: np.ndarray) -> bool:
    """Whether the lines resolve a root's resonance: its half-power band ``2 zeta f`` is at
    least the line spacing there (a negative damping resolves nothing)."""
    width = 2.0 * max(root.zeta, 0.0) * root.freq_hz
    return width >= float(line_spacing_at(line_freq_hz, root.freq_hz)[0])


def screen_unresolved(roots: list[BandRoot], candidates: list[BandRoot],
                       line_freq_hz: np.ndarray) -> None:
    """Criteria 2 and 3 for roots whose phase the lines do not see (negative damping or low
    MPC, kept so far).

    Such a root is left to criterion 4 (its frequency must repeat in another band), unless
    a resolved root of the same band (half-power band ``2 zeta f`` at least a line spacing)
    that passed criteria 1-3 lies within one line spacing: that mode's own resonance spans
    the lines there, and a lightly damped root inside it is noise (with every unresolved root
    spared, the report's noise gave one at 318.65 Hz beside the 318.57 Hz mode, selected as
    a second mode). Two unresolved roots closer than a line
    spacing can both be modes: the payload's suspension modes at 1.29 and 2.83 Hz, 1.5 Hz
    apart with lines 2.25 Hz apart.
    """
    spared = {id(r) for r in candidates}  # by identity: roots hold arrays, == is ambiguous

    def df(f: float) -> float:
        return float(line_spacing_at(line_freq_hz, f)[0])

    for root in candidates:
        crowded = any(
            other.band == root.band and id(other) not in spared and not other.rejected
            and _resolved_by_lines(other, line_freq_hz)
            and abs(other.freq_hz - root.freq_hz) < df(root.freq_hz)
            for other in roots)
        if crowded:
            root.rejected = "negative damping" if root.zeta < 0 else "low MPC"
            root.mpc_applied = root.damping_applied = True


def cluster_repeated(roots: list[BandRoot], tol: float, line_freq_hz: np.ndarray) -> None:
    """Criterion 4: group surviving roots of different bands that are the same mode.

    Two roots of different bands may be the same mode when their frequencies differ by at
    most :func:`repeat_tolerance_hz` of the wider of the two and their damping ratios by at
    most a factor 2, positive both. The damping check is skipped when neither root's phase is
    seen by the lines (:func:`phase_seen_by_lines`): their damping is the noise's, as is its
    sign (such roots may have come through criterion 2 with a negative one). On the payload
    at 12 sensors, 1-1158 Hz, seed 2, the 1.29 Hz mode's estimates in bands 0 and 1 are 0.0002
    Hz apart with damping -0.3 % and 1.9 %. The candidate pairs are merged closest first
    (distance over tolerance), a group holding at most one root per band and every pair in
    it within tolerance, so that a noise root near a true mode cannot take the place of that
    mode's own repeat (the band with both keeps the nearer one). Groups of one root are
    rejected ("not repeated"), groups with no positive damping too ("negative damping").
    """
    alive = sorted((r for r in roots if not r.rejected), key=lambda r: r.freq_hz)
    f = np.array([r.freq_hz for r in alive])
    z = np.array([max(abs(r.zeta), 1e-12) for r in alive])
    t = repeat_tolerance_hz(f, z, distance_to_nearest_line(line_freq_hz, f), tol)

    def close(i: int, j: int) -> bool:
        return _alike(alive[i], alive[j], t[i], t[j])

    pairs = sorted((abs(f[i] - f[j]) / max(t[i], t[j]), i, j)
                   for i in range(len(alive)) for j in range(i + 1, len(alive)) if close(i, j))
    group = {i: [i] for i in range(len(alive))}  # group label -> members
    label = list(range(len(alive)))
    for _, i, j in pairs:
        a, c = label[i], label[j]
        if a == c or not all(close(p, q) for p in group[a] for q in group[c]):
            continue
        for q in group[c]:
            label[q] = a
        group[a] += group.pop(c)
    k = 0
    for members in sorted(group.values(), key=lambda g: f[g[0]]):
        if len(members) < 2:
            alive[members[0]].rejected = "not repeated"
            continue
        if all(alive[i].zeta <= 0 for i in members):
            for i in members:
                alive[i].rejected = "negative damping"
                alive[i].damping_applied = True
            continue
        for i in members:
            alive[i].cluster = k
        k += 1


def reject_edge_cut_only(roots: list[BandRoot]) -> None:
    """Criterion 3 for the estimates that were spared it because an edge of their band cuts
    their resonance (``edge_cut``): the mode found (criterion 4's cluster) must hold an
    estimate from a band that holds its whole half-power band and that passed criterion 3.
    Otherwise the spared estimates are rejected as "low MPC", and the rest of the cluster as
    "not repeated" if fewer than two remain.

    Why a whole band, not any other: a heavily damped root has a wide half-power band, cut by
    most bands. With the report's noise (12 sensors, 1-1158 Hz, seed 10) a computational root
    near the 992 Hz mode, 978.6 Hz with 4.2 % damping and MPC 0.48 in band 20, paired with
    band 21's 986.0 Hz (4.3 %, MPC 0.83, cut too) and was selected, when any estimate that
    passed criterion 3 confirmed a spared one. A band edge inside the layout is also the edge
    of two bands that abut (with 50 % overlap, bands k and k + 2), so a root there is cut in
    both and must be confirmed by the band centred on it.
    """
    members: dict[int, list[BandRoot]] = {}
    for r in roots:
        if r.cluster >= 0 and not r.rejected:
            members.setdefault(r.cluster, []).append(r)
    for group in members.values():
        spared = [r for r in group if r.edge_cut and not r.mpc_applied]
        # A whole band's estimate whose phase the lines see (an unseen root's MPC is the noise's).
        if not spared or any(r.phase_seen and not r.edge_cut and r.mpc_applied for r in group):
            continue
        for r in spared:
            r.rejected, r.mpc_applied, r.cluster = "low MPC", True, -1
        rest = [r for r in group if not r.rejected]
        if len(rest) < 2:
            for r in rest:
                r.rejected, r.cluster = "not repeated", -1


def _alike(a: BandRoot, b: BandRoot, t_a: float, t_b: float) -> bool:
    """Criterion 4's test of two roots, each with its tolerance (Hz, :func:`repeat_tolerance_hz`):
    different bands, frequencies within the wider tolerance, damping within a factor 2 and
    positive both, unless neither root's phase is seen (:func:`cluster_repeated`)."""
    if a.band == b.band or abs(a.freq_hz - b.freq_hz) > max(t_a, t_b):
        return False
    if not (a.phase_seen or b.phase_seen):
        return True
    za, zb = max(abs(a.zeta), 1e-12), max(abs(b.zeta), 1e-12)
    return a.zeta > 0 and b.zeta > 0 and 0.5 <= za / zb <= 2.0


def _repeats(a: BandRoot, b: BandRoot, tol: float, line_freq_hz: np.ndarray) -> bool:
    """Whether two roots of different bands may be one mode by criterion 4's test
    (:func:`_alike`, with their tolerances)."""
    f = np.array([a.freq_hz, b.freq_hz])
    z = np.array([max(abs(a.zeta), 1e-12), max(abs(b.zeta), 1e-12)])
    t = repeat_tolerance_hz(f, z, distance_to_nearest_line(line_freq_hz, f), tol)
    return _alike(a, b, float(t[0]), float(t[1]))


def reject_top_nested_only(roots: list[BandRoot], layout_hz, high_band: int, tol: float,
                           line_freq_hz: np.ndarray) -> None:
    """A mode found (criterion 4's cluster) only by the layout's bands that end at the
    record's last line must be found by the high-edge band ``high_band`` too
    (:func:`ssid.band_edges.high_edge_band`); otherwise its roots are rejected as "not
    repeated by the high-edge band".

    Why: those bands are nested (the top part-band lies wholly inside the band before it),
    so they share every line of the part-band and its noise, and a root fitted to that noise
    comes out of both. On the payload's random record with one shaker (16 sensors,
    20-1500 Hz) a 1456.5 Hz root, 0.04 % damping and MPC 0.96, was confirmed by the bands
    1376.7-1500 and 1438.3-1500 Hz; the structure has no mode between 1318.7 and 1826 Hz.
    The high-edge band holds other lines below them, and so other computational roots: it
    did not repeat that root, and repeats the 1318.7 Hz mode of the stepped-sine record, which
    the nested top bands alone find. Any of its roots that passed criteria 1-3 confirms (its
    resolved ones are otherwise left out of criterion 4, "resolved (high-edge band)"), by
    criterion 4's test (:func:`cluster_repeated`) against every estimate of the mode.

    ``layout_hz``: the layout's bands (the edge bands are not among them).
    """
    tiny = 1e-9 * (float(line_freq_hz[-1]) - float(line_freq_hz[0]))
    top = {b for b, (_, hi) in enumerate(layout_hz) if hi >= float(line_freq_hz[-1]) - tiny}
    members: dict[int, list[BandRoot]] = {}
    for r in roots:
        if r.cluster >= 0 and not r.rejected:
            members.setdefault(r.cluster, []).append(r)
    third = [q for q in roots if q.band == high_band
             and q.rejected in ("", "resolved (high-edge band)")]
    for group in members.values():
        regular = [r for r in group if r.band != high_band and not r.low_edge]
        if any(r.band == high_band for r in group) or not all(r.band in top for r in regular):
            continue
        if any(all(_repeats(q, r, tol, line_freq_hz) for r in regular) for q in third):
            continue
        for r in group:
            r.rejected, r.cluster = "not repeated by the high-edge band", -1


def reject_inside_resolved(roots: list[BandRoot], bands_hz, line_freq_hz: np.ndarray) -> None:
    """Of the modes found (criterion 4's clusters), reject one whose resonance the lines do not
    resolve (its representative's half-power bandwidth ``2 zeta f`` narrower than the line
    spacing) when it lies inside the half-power band ``[f - zeta f, f + zeta f]`` of a mode
    found that they do resolve: its roots are rejected as "inside a resolved mode's
    half-power band".

    Why: the resolved mode's resonance sets the response at every line of its half-power
    band (at least 71 % of its peak there), so a root narrower than the line spacing inside
    it is fitted to the noise on that resonance; the overlapping bands share those lines and
    their noise, so it repeats and passes criterion 4. With the report's noise (12 sensors,
    1-1158 Hz, df = 2.26 Hz, seeds 0-30) two such roots were selected beside the 318.57 Hz
    mode (half-power band +-6.4 Hz): 3.3 Hz above it on seed 10 (damping 0.01-0.02 %, MPC
    0.40-0.65; criteria 2 and 3 spared it, :func:`phase_seen_by_lines`, and no resolved
    root lay within the one line spacing of :func:`screen_unresolved`) and 3.8 Hz above it
    on seed 19 (damping 0.17-0.18 %, MPC 0.83-0.88, passing criteria 1-3 outright). A true
    mode there would need a damping ratio below ``df / (2 f)`` (0.35 % at 320 Hz) to be
    unresolved; the lines could not tell it from that noise. The payload's unresolved modes
    (the suspension modes at 1.29, 2.83 and 6.21 Hz) have no resolved mode near them.
    """
    reps = pick_representatives(roots, bands_hz)

    wide = [r for r in reps if _resolved_by_lines(r, line_freq_hz)]
    inside = {u.cluster for u in reps  # representatives have positive damping: zeta f > 0
              if not _resolved_by_lines(u, line_freq_hz)
              and any(abs(r.freq_hz - u.freq_hz) < r.zeta * r.freq_hz for r in wide)}
    for q in roots:
        if q.cluster in inside and not q.rejected:
            q.rejected = "inside a resolved mode's half-power band"


#: Two modes found whose shapes agree at the sensors to this MAC, within
#: :data:`ECHO_HALF_POWER_BANDS` half-power bandwidths of each other, are one mode seen twice.
ECHO_MAC_MIN = 0.9
ECHO_HALF_POWER_BANDS = 2.0


def reject_echoes(roots: list[BandRoot], bands_hz, data: list[Step1Data | None]) -> None:
    """Of two modes found (criterion 4's clusters) whose representatives lie within
    :data:`ECHO_HALF_POWER_BANDS` half-power bandwidths ``2 zeta f`` (the wider of the two) of
    each other and whose shapes agree to :data:`ECHO_MAC_MIN` (MAC), keep the one holding the
    larger share of the FRF (:func:`frf_share`, each in its own band); the other's roots are
    rejected as "same shape as a stronger mode".

    Why: neighbouring bands share half their lines, so a root fitted to the noise on the
    skirt of a mode's resonance comes out in both bands and passes criterion 4. On the skirt
    the response has the mode's shape, so the root has it too. Within two half-power
    bandwidths a mode's resonance is still at least a quarter of its peak, and sensors that
    see two such roots with one shape cannot tell them apart (their mode matrix is near
    singular, see :func:`strongest_roots`). On 18 noisy payload records (10, 12, 16 EfI
    sensors, seeds 1-3, one BLAS thread) five such pairs were selected, 0.02-0.94 bandwidths
    apart with MAC 0.91-0.98 (81.8 Hz beside 78.9 Hz; 114.0 and 116.0 beside 117.5; 559.1
    beside 558.7; 997.0 beside 992.1); in every one the root kept is the mode (the shares of
    the 81.8 and 114.0 Hz roots: 0.35 % and 1.75 %, against 96-100 % for the modes).
    Noise-free, no pair of modes came within three bandwidths with a MAC above 0.5.
    """
    reps = pick_representatives(roots, bands_hz)
    if len(reps) < 2:
        return
    shapes = root_shapes(reps, reps[0].theta.size // 2)  # theta is (2n,): [phi; lambda phi]
    mac = modal_assurance(shapes, shapes)
    shares: dict[int, dict[int, float]] = {}  # band -> id(root) -> share, one fit per band

    def share_of(r: BandRoot) -> float:
        if r.band not in shares:
            lo, hi = bands_hz[r.band]
            band = [q for q in roots if q.band == r.band and lo <= q.freq_hz <= hi and q.zeta > 0]
            try:
                values = frf_share(data[r.band], band)
            except (IdentificationError, np.linalg.LinAlgError):
                values = np.full(len(band), np.nan)
            shares[r.band] = {id(q): float(v) for q, v in zip(band, values)}  # roots hold arrays
        return shares[r.band].get(id(r), np.nan)

    weaker: set[int] = set()
    for a in range(len(reps)):
        for b in range(a + 1, len(reps)):
            ra, rb = reps[a], reps[b]
            width = max(2 * ra.zeta * ra.freq_hz, 2 * rb.zeta * rb.freq_hz)
            if (a in weaker or b in weaker or mac[a, b] < ECHO_MAC_MIN
                    or abs(ra.freq_hz - rb.freq_hz) > ECHO_HALF_POWER_BANDS * width):
                continue
            sa, sb = share_of(ra), share_of(rb)
            if not (np.isfinite(sa) and np.isfinite(sb)):
                continue
            weaker.add(b if sb < sa else a)
    for i in weaker:
        for q in roots:
            if q.cluster == reps[i].cluster and not q.rejected:
                q.rejected = "same shape as a stronger mode"


def pick_representatives(roots: list[BandRoot], bands_hz) -> list[BandRoot]:
    """One root per cluster: the one farthest from an edge of its band (least edge effect),
    among those with positive damping (a cluster's others came through criteria 2 and 4 only
    because the lines do not see their damping), never one spared criterion 3 because an edge
    of its band cuts its resonance (it confirms the whole band's estimate that passed, see
    :func:`reject_edge_cut_only`; with a wider damping estimate it could lie farther from
    its edge), never an edge band's (low or high: it confirms;
    holding the most modes for the same n DOFs, its estimates of the low modes are the most
    compromised: 1.274 and 1.257 Hz where the other bands gave 1.284 and 1.289 Hz for the
    1.287 Hz mode on two payload records).

    Only band edges inside the record count: at the record's own first or last line every
    band holding the root is cut alike (the two part-bands at each end share that edge with
    their neighbours), so there the band whose other edge is farther gives the better
    estimate. For bands of equal width away from the ends this is the root nearest the centre.
    """
    lo_rec = min(lo for lo, _ in bands_hz)
    hi_rec = max(hi for _, hi in bands_hz)

    def margin(r: BandRoot) -> float:
        lo, hi = bands_hz[r.band]
        return min(r.freq_hz - lo if lo > lo_rec else np.inf,
                   hi - r.freq_hz if hi < hi_rec else np.inf)

    best: dict[int, BandRoot] = {}
    for r in roots:
        if (r.rejected or r.cluster < 0 or r.zeta <= 0 or r.low_edge or r.high_edge
                or (r.edge_cut and not r.mpc_applied)):
            continue
        cur = best.get(r.cluster)
        if cur is None or margin(r) > margin(cur):
            best[r.cluster] = r
    return sorted(best.values(), key=lambda r: r.freq_hz)
