"""Pseudo DOFs with the number of partitions chosen from the data (beyond the report).

The report stacked two partitions (Eq. 5.24); a record holding more than about 2n modes for
n sensors needs more (:mod:`ssid.pseudo_dof`). :func:`identify_pseudo_dof_auto` raises p
until the models with p and p + 1 partitions find each other's consistent roots again (a
stabilisation test across model orders), and :func:`plot_partition_scan` draws that scan.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import IdentificationError
from .frf import FRFData
from .pseudo_dof import PseudoDofResult, _copies_of, identify_pseudo_dof, matched_one_to_one

__all__ = ["PartitionScan", "identify_pseudo_dof_auto", "plot_partition_scan"]


@dataclass
class PartitionScan:
    """How :func:`identify_pseudo_dof_auto` chose the number of partitions.

    Attributes
    ----------
    chosen : the p used.
    settled : whether the chosen p and p + 1 met ``repeat_min`` both ways (else the chosen
        p is the best fraction seen).
    repeat_min, repeat_rtol : the rule's thresholds.
    roots_hz : {p: (m_p,)} every oscillatory root of each model computed (p tried and the
        last p + 1), Hz; ``consistent`` {p: (m_p,) bool} its consistency verdict (in band,
        positive damping, consistency); ``repeated`` {p: (m_p,) bool} for each p tried,
        whether the p + 1 model repeats it. The stabilisation diagram
        (:func:`plot_partition_scan`) draws these.
    n_partitions, n_consistent, n_consistent_next, n_repeated, agreement : (k,) per p tried
        (each compared with p + 1): p, its consistent roots, the p + 1 model's, how many of
        p's the p + 1 model repeats (one to one: as many of the p + 1 model's are repeated by
        p), and the fraction of the larger count that is repeated (the rule's measure).
    """

    chosen: int
    settled: bool
    repeat_min: float
    repeat_rtol: float
    roots_hz: dict[int, np.ndarray] = field(default_factory=dict)
    consistent: dict[int, np.ndarray] = field(default_factory=dict)
    repeated: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def n_partitions(self) -> np.ndarray:
        return np.array(sorted(self.repeated), dtype=int)

    @property
    def n_consistent(self) -> np.ndarray:
        return np.array([int(self.consistent[p].sum()) for p in self.n_partitions], dtype=int)

    @property
    def n_repeated(self) -> np.ndarray:
        return np.array([int(self.repeated[p].sum()) for p in self.n_partitions], dtype=int)

    @property
    def n_consistent_next(self) -> np.ndarray:
        return np.array([int(self.consistent[p + 1].sum()) for p in self.n_partitions], dtype=int)

    @property
    def agreement(self) -> np.ndarray:
        return _agreement(self.n_repeated, self.n_consistent, self.n_consistent_next)


def _agreement(n_repeated, n_consistent, n_consistent_next) -> np.ndarray | float:
    """Fraction of the p and p + 1 models' consistent roots that repeat each other (matched one
    to one, so the larger count is the denominator); 0 where neither has any."""
    return n_repeated / np.maximum(np.maximum(n_consistent, n_consistent_next), 1)


def identify_pseudo_dof_auto(frf: FRFData, consistency_min: float = 0.8, max_partitions: int = 6,
                             repeat_min: float = 0.8, repeat_rtol: float = 0.01) -> PseudoDofResult:
    """Pseudo-DOF model with the number of partitions chosen from the data (stabilisation).

    A pseudo model of order p n holds at most p n modes, and the report's p = 2 is too few
    when the record holds more than about 2n modes (21 modes in 1-2100 Hz at 10 sensors in
    Table 6.18's case). A structural root of the model with p partitions is found again by
    the model with p + 1 (the stabilisation diagram's test across model orders, as criterion
    4 of band processing repeats a root across bands); a computational one comes and goes.
    p = 2, 3, ... is raised until the p and p + 1 models agree both ways: at least
    ``repeat_min`` of the consistent roots of each repeat in the other within
    ``repeat_rtol`` in frequency (one to one, so the larger count is the denominator), and
    the repeated roots are the structural ones (``repeated``): consistency and repetition
    are both required. A one-way test let p stop where the p + 1 model found modes that p
    did not (10 payload sensors at 1-600 Hz: p = 2 held 9 of 11 modes, p = 3 all 11).

    Parameters
    ----------
    frf : as for :func:`identify_pseudo_dof`.
    consistency_min : threshold of the partition-consistency indicator.
    max_partitions : largest p considered (p + 1 is computed to test it).
    repeat_min : fraction of consistent roots of the p and of the p + 1 model that must
        repeat in the other.
    repeat_rtol : relative frequency tolerance of a repeat.

    Returns
    -------
    PseudoDofResult with ``repeated`` and ``scan`` set. When no p meets ``repeat_min``
    (noisy data: the least-squares roots of Eq. 3.7 move with the order) the p with the
    largest agreeing fraction is used and ``scan.settled`` is False.
    """
    results = {2: identify_pseudo_dof(frf, consistency_min, 2)}
    repeated_by_p: dict[int, np.ndarray] = {}
    for p in range(2, max_partitions + 1):
        try:
            results[p + 1] = identify_pseudo_dof(frf, consistency_min, p + 1)
        except IdentificationError:  # too few lines per partition: p is the last one testable
            break
        a, b = results[p], results[p + 1]
        rep = matched_one_to_one(a.freq_hz[a.structural], b.freq_hz[b.structural], repeat_rtol)
        repeated_by_p[p] = np.zeros(a.freq_hz.size, dtype=bool)
        repeated_by_p[p][a.structural] = rep
        if rep.size and _agreement(rep.sum(), rep.size, b.structural.sum()) >= repeat_min:
            break
    if not repeated_by_p:
        raise IdentificationError("too few lines to compare pseudo models of 2 and 3 partitions")
    scan = PartitionScan(0, False, repeat_min, repeat_rtol,
                         roots_hz={p: r.freq_hz for p, r in results.items()},
                         consistent={p: r.structural.copy() for p, r in results.items()},
                         repeated=repeated_by_p)
    ps, frac = scan.n_partitions, scan.agreement
    scan.settled = bool(frac[-1] >= repeat_min and scan.n_consistent[-1] > 0)
    scan.chosen = int(ps[-1] if scan.settled else ps[int(np.argmax(frac))])
    res = results[scan.chosen]
    res.repeated = repeated_by_p[scan.chosen]
    res.structural = res.structural & res.repeated
    res.second_copy = _copies_of(res.lam, res.structural)
    res.scan = scan
    return res


def plot_partition_scan(path: str, res: PseudoDofResult, true_freq_hz: np.ndarray | None = None) -> None:
    """Stabilisation diagram of the partition scan: each pseudo model's roots against
    frequency, one row per number of partitions, marked by verdict (repeated by the next
    model, consistent only, computational); the chosen model's row is shaded, its structural
    roots drawn as green lines, and ``true_freq_hz`` (Hz; known modes, or an FE model's) as
    dotted ones. ``res`` must come from :func:`identify_pseudo_dof_auto`."""
    if res.scan is None:
        raise ValueError("the stabilisation diagram needs a scan (identify_pseudo_dof_auto)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc = res.scan
    fig, ax = plt.subplots(figsize=(9, 5))
    ax.axhspan(sc.chosen - 0.4, sc.chosen + 0.4, color="0.9", zorder=0)
    marks = (("repeated by the next model", "o", "tab:green"),
             ("consistent, not repeated", "x", "tab:orange"),
             ("consistent (top row: no next model)", "+", "tab:blue"),
             ("computational", ".", "0.6"))
    seen = set()
    for p, f in sc.roots_hz.items():
        cons = sc.consistent[p]
        none = np.zeros(f.size, dtype=bool)
        if p in sc.repeated:
            rep = sc.repeated[p]
            groups = (rep, cons & ~rep, none, ~cons)
        else:  # the p + 1 model of the last p tried: nothing to compare it with
            groups = (none, none, cons, ~cons)
        for (label, mk, col), sel in zip(marks, groups, strict=True):
            if sel.any():
                ax.scatter(f[sel], np.full(int(sel.sum()), p), marker=mk, color=col, s=28,
                           zorder=2, label=None if label in seen else label)
                seen.add(label)
    for f in res.freq_hz[res.structural]:
        ax.axvline(f, color="tab:green", lw=0.6, alpha=0.5, zorder=1)
    if true_freq_hz is not None:
        for f in true_freq_hz:
            ax.axvline(f, color="k", lw=0.5, ls=":", zorder=1)
    # Up to the highest root in the band (consistent roots are in the band by definition).
    in_band = [f[sc.consistent[p]] for p, f in sc.roots_hz.items()]
    hi = max((float(np.max(f)) for f in in_band if f.size), default=1.0)
    ax.set_xlim(0.0, hi * 1.05)
    ax.set_yticks(sorted(sc.roots_hz))
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("partitions P (model order P n)")
    ax.set_title(f"pseudo-DOF roots per number of partitions (shaded: P = {sc.chosen}, "
                 f"{'settled' if sc.settled else 'not settled'})")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


