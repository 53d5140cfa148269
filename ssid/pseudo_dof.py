"""Pseudo degrees of freedom (report section 5.3, Eq. 5.24): more modes than sensors.

The record is split at its middle line; the low-frequency half is stacked on top of the
high-frequency half, so that each "pseudo line" k carries ``[H(w_k); H(w_k+N/2)]``: 2n pseudo
outputs for n sensors. Step 1 then has a model of order 2n, and Eq. 3.12 gives up to 2n modes.
Each element of the stacked regressor keeps its own frequency (``H/(j w)``, ``H/w^2`` with the
w of its half).

The report split the record in two. We allow ``p`` contiguous partitions of ``N // p`` lines
each (``n_partitions``; pseudo line k carries ``[H(w_k); H(w_k+L); ...]``, a model of order
``p n``): where the record holds more than 2n modes, two partitions cannot hold them all
(the payload of Table 6.18: 21 modes in 1-2100 Hz at 10 sensors, docs/replication.md
section 5). The top ``N mod p`` lines are left out.

Step 1 and the eigenproblem are what the report did. To tell structural from computational
modes (the report asks for an indicator) we use the *partition consistency* of a mode:
a structural mode lives in the partition whose lines hold its frequency (its "own"
partition; the nearest one for a root between or outside them). ``q = |phi_own|^2 / |phi|^2``
is near 1 for structural modes and spreads over the partitions for computational ones;
where roots repeat (a mode found more than once by a model of spare order) it is taken over
their common subspace (:func:`_cluster_consistency`).
:func:`identify_pseudo_dof_auto` chooses p from the data and adds a second indicator: a
structural root is found again by the model with one partition more (a stabilisation test
across model orders); computational roots come and go.

Step 2 (the report left it open) is done on the measured FRFs, not on the pseudo DOFs:
:mod:`ssid.pseudo_dof_step2` (its names are importable from here too).

The earlier attempt, the pseudo DOFs themselves as generalised coordinates
(``H(w) = sum_r u_r R_r(w) P_w theta_r (theta_r^T D_p)``, ``P_w`` the partition that carries
w, ``D_p = [D_f; ...; D_f]``), is kept as :func:`pseudo_dof_fit_error` for comparison: it
cannot hold the measured FRFs (62 % relative RMS error on the payload of Table 6.18 with two
partitions), because the pseudo shapes of a mode in its other partitions are not zero and not
physical.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from .errors import IdentificationError
from .frf import FRFData, require_response
from .modal import modal_phase_collinearity, root_frequency_damping
from .pseudo_dof_step2 import (
    PseudoDofMCK,
    PseudoModalModel,
    free_residue_error,
    frf_relative_error,
    mck_accelerance,
    modal_model_accelerance,
    pseudo_dof_mck,
    pseudo_modal_model,
)
from .solvers import solve_ls
from .step2 import state_space_modes

__all__ = [
    "PseudoDofMCK",
    "PartitionScan",
    "PseudoDofResult",
    "PseudoModalModel",
    "free_residue_error",
    "frf_relative_error",
    "identify_pseudo_dof",
    "identify_pseudo_dof_auto",
    "matched_one_to_one",
    "mck_accelerance",
    "modal_model_accelerance",
    "pseudo_dof_fit_error",
    "pseudo_dof_mck",
    "plot_partition_scan",
    "pseudo_modal_model",
]


@dataclass
class PseudoDofResult:
    """Modes of the pseudo-DOF model.

    Attributes
    ----------
    freq_hz, zeta, mpc, consistency : (m,) per oscillatory root, ascending frequency.
    structural : (m,) bool, the indicator's verdict (in band, positive damping,
        consistency >= threshold; from :func:`identify_pseudo_dof_auto` also repeated).
    lam : (m,) roots; theta : (2 p n, m) state eigenvectors of the pseudo model.
    u : (m,) complex modal scale factors from the step-2 attempt.
    split_hz : (p - 1,) the frequencies at which the record was split (between partitions).
    own : (m,) int, the partition carrying each root (0 = lowest frequencies).
    repeated : (m,) bool or None, whether the model with one partition more finds the root
        again (:func:`identify_pseudo_dof_auto`; None from :func:`identify_pseudo_dof`).
    scan : how the number of partitions was chosen, or None.
    second_copy : (m,) bool, a root within 0.1 % of a structural one that is not itself
        structural: a copy of that mode, holding its response in other partitions
        (:func:`_cluster_consistency`).
    """

    freq_hz: np.ndarray
    zeta: np.ndarray
    mpc: np.ndarray
    consistency: np.ndarray
    structural: np.ndarray
    lam: np.ndarray
    theta: np.ndarray
    u: np.ndarray
    split_hz: np.ndarray
    own: np.ndarray
    repeated: np.ndarray | None = None
    scan: PartitionScan | None = None
    second_copy: np.ndarray | None = None

    @property
    def n_partitions(self) -> int:
        return self.split_hz.size + 1


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


def _stack(frf: FRFData, n_partitions: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Pseudo lines: (L, p n, n_in) accelerances and (L, p n) frequencies (rad/s), L = N // p."""
    if frf.H_reaction is not None:
        raise IdentificationError("pseudo DOFs with measured reactions are not supported")
    ne = frf.n_freq // n_partitions
    w = frf.omega
    blocks = [slice(i * ne, (i + 1) * ne) for i in range(n_partitions)]
    H = np.concatenate([frf.H[b] for b in blocks], axis=1)
    W = np.concatenate([np.repeat(w[b, None], frf.n_out, 1) for b in blocks], axis=1)
    return H, W, ne


def _own_partition(f_hz: np.ndarray, freq_hz: np.ndarray, ne: int, n_partitions: int) -> np.ndarray:
    """Index of the partition whose lines hold each frequency (the nearest one otherwise)."""
    lo = np.array([freq_hz[i * ne] for i in range(n_partitions)])
    hi = np.array([freq_hz[(i + 1) * ne - 1] for i in range(n_partitions)])
    gap = np.maximum(lo[None, :] - f_hz[:, None], 0) + np.maximum(f_hz[:, None] - hi[None, :], 0)
    return np.argmin(gap, axis=1)


def identify_pseudo_dof(frf: FRFData, consistency_min: float = 0.8,
                        n_partitions: int = 2, weight_exponent: float = 0.0) -> PseudoDofResult:
    """Step 1 with pseudo DOFs (Eq. 5.24), Eq. 3.12, the indicator, and our step-2 attempt.

    Parameters
    ----------
    frf : FRFData without reactions and without blanked values, noise-free or not.
    consistency_min : threshold of the partition-consistency indicator.
    n_partitions : p, the number of partitions stacked (the report's Eq. 5.24: 2); the
        model has order p n for n sensors.
    weight_exponent : each pseudo output's equations (Eq. 3.7) on pseudo line k weighted by
        ``omega_k ** weight_exponent``, omega_k the frequency of that output's partition at
        line k. 0 (default) is the report's least squares, every line alike; below 0 the
        lower lines of each partition weigh more. Not chosen from the data: on the payload of
        Table 6.18 it trades targets found between cases (docs/replication.md, section 5).
    """
    require_response(frf)
    if not frf.valid_mask().all():
        raise IdentificationError("pseudo DOFs need a record without blanked values")
    if n_partitions < 2:
        raise ValueError("pseudo DOFs need at least 2 partitions")
    if 2 * (frf.n_freq // n_partitions) * frf.n_in < 2 * n_partitions * frf.n_out + frf.n_in:
        # fewer real equations per pseudo output than unknowns (Eq. 3.7 per column)
        raise IdentificationError(f"{frf.n_freq} lines cannot make {n_partitions} partitions "
                                  f"for {frf.n_out} outputs (too few lines per partition)")
    H, W, ne = _stack(frf, n_partitions)
    n2, n_in = H.shape[1], frf.n_in
    h = np.swapaxes(H, 1, 2)  # (Ne, n_in, 2n)
    Wt = W[:, None, :]
    eye = np.broadcast_to(np.eye(n_in), (ne, n_in, n_in)).astype(complex)
    Z = np.concatenate([h / (1j * Wt), -h / Wt**2, -eye], axis=2).reshape(-1, 2 * n2 + n_in)
    Y = -h.reshape(-1, n2)
    if weight_exponent == 0.0:
        X = solve_ls(np.vstack([Z.real, Z.imag]), np.vstack([Y.real, Y.imag])).T
    else:
        X = _weighted_rows(Z, Y, W, n_in, frf.n_out, n_partitions, weight_exponent)
    C_hat, K_hat = X[:, :n2], X[:, n2 : 2 * n2]
    modes = state_space_modes(C_hat, K_hat)
    m = modes.n_pairs
    wn, zeta = root_frequency_damping(modes.lam[:m])
    f = wn / (2 * np.pi)
    split = np.array([0.5 * (frf.freq_hz[i * ne - 1] + frf.freq_hz[i * ne])
                      for i in range(1, n_partitions)])
    n = frf.n_out
    th = modes.theta_x[:, :m].reshape(n_partitions, n, m)
    own = _own_partition(f, frf.freq_hz, ne, n_partitions)
    consistency = _cluster_consistency(modes.lam[:m], th, own)
    in_band = (f >= frf.freq_hz[0]) & (f <= frf.freq_hz[n_partitions * ne - 1])
    structural = in_band & (zeta > 0) & (consistency >= consistency_min)
    shapes = th[own, :, np.arange(m)].T  # (n, m): each root's shape in its own partition
    mpc = modal_phase_collinearity(shapes)
    u = _pseudo_scale_factors(frf, modes, ne, n_partitions)
    res = PseudoDofResult(freq_hz=f, zeta=zeta, mpc=mpc, consistency=consistency,
                          structural=structural, lam=modes.lam[:m], theta=modes.theta[:, :m],
                          u=u, split_hz=split, own=own)
    res.second_copy = _copies_of(res.lam, structural)
    return res


def _weighted_rows(Z: np.ndarray, Y: np.ndarray, W: np.ndarray, n_in: int, n: int,
                   n_partitions: int, exponent: float) -> np.ndarray:
    """Eq. 3.7 on the pseudo lines, each line's equation of a pseudo output weighted by its
    own omega**exponent: (p n, 2 p n + n_in). A row of X (one pseudo output) is its own
    least-squares problem, so the rows of one partition share one weighted solve."""
    X = np.empty((Y.shape[1], Z.shape[1]))
    for q in range(n_partitions):
        w = np.repeat(W[:, q * n] ** exponent, n_in)[:, None]  # (Ne n_in, 1)
        Zq, Yq = w * Z, w * Y[:, q * n:(q + 1) * n]
        X[q * n:(q + 1) * n] = solve_ls(np.vstack([Zq.real, Zq.imag]), np.vstack([Yq.real, Yq.imag])).T
    return X


#: Roots within this fraction of |lambda| of each other are one cluster: one mode found more
#: than once by the spare order of the pseudo model, or modes with one root (a symmetric
#: structure's pair), which :func:`_cluster_consistency` tells apart.
CLUSTER_RTOL = 1e-3


def _near(lam: np.ndarray) -> np.ndarray:
    """(m, m) bool: root i lies within :data:`CLUSTER_RTOL` of root j's |lambda|."""
    return np.abs(lam[:, None] - lam[None, :]) <= CLUSTER_RTOL * np.abs(lam)[None, :]


def _clusters(lam: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the roots that lie within :data:`CLUSTER_RTOL` of each other
    (chained), each with more than one root."""
    near = _near(lam)
    n_groups, label = connected_components(csr_matrix(near | near.T), directed=False)
    groups = [np.flatnonzero(label == g) for g in range(n_groups)]
    return [g for g in groups if g.size > 1]


def _cluster_consistency(lam: np.ndarray, th: np.ndarray, own: np.ndarray) -> np.ndarray:
    """Partition consistency ``q = |phi_own|^2 / |phi|^2`` of each root (``th`` (p, n, m), the
    displacement shapes per partition; ``own`` (m,)), taken over its cluster where roots repeat.

    A pseudo model holds up to p n modes; where the record holds fewer (every DOF measured,
    or more partitions than its modes need), the spare order reproduces a mode more than
    once, at one root. Its eigenvectors are then any basis of their invariant subspace, so
    one root's q says nothing: on a free beam with all 8 DOFs measured, the 3-partition
    model gave the 2066.7 Hz mode three times with q 0.15, 0.03 and 0.002, while the
    subspace holds a vector entirely in the mode's own partition. So for a cluster of k
    roots, q is taken over the subspace: the k stationary values of ``|P_own v|^2 / |v|^2``
    over v in it (the eigenvalues of ``U^H P_own U``, U an orthonormal basis), the largest
    given to the root with the largest q of its own, and so on. A mode found k times gets
    one value near 1 and k - 1 near 0 (the copies hold its response in the other
    partitions); two modes with one root and different shapes get two near 1.
    """
    p, n, m = th.shape
    energy = np.sum(np.abs(th) ** 2, axis=1)  # (p, m)
    q = energy[own, np.arange(m)] / energy.sum(axis=0)
    flat = th.reshape(p * n, m)
    for idx in _clusters(lam):
        U = sla.orth(flat[:, idx])
        block = own[idx[np.argmax(q[idx])]]  # the cluster's roots agree to 0.1 %: one partition
        Uo = U[block * n:(block + 1) * n]
        mu = np.clip(np.linalg.eigvalsh(Uo.conj().T @ Uo)[::-1], 0.0, 1.0)
        q_new = np.zeros(idx.size)
        q_new[: mu.size] = mu  # a rank-deficient cluster: its last roots hold nothing new
        q[idx[np.argsort(-q[idx])]] = q_new
    return q


def _copies_of(lam: np.ndarray, structural: np.ndarray) -> np.ndarray:
    """(m,) bool: the roots not ``structural`` within :data:`CLUSTER_RTOL` of a
    structural one: copies of that mode, which hold its response in other partitions."""
    return ~structural & np.any(_near(lam)[:, structural], axis=1)


def matched_one_to_one(freq_hz: np.ndarray, other_hz: np.ndarray, rtol: float) -> np.ndarray:
    """For each frequency, whether a root of ``other_hz`` within ``rtol`` of it repeats it.

    Matched one to one, closest pairs first (as criterion 4 of band processing), so that two
    roots of one model beside one mode are not both confirmed by its single estimate. The
    distance is relative to ``freq_hz`` (Hz, (m,)); ``other_hz`` (Hz, (k,)); returns (m,) bool.
    """
    freq_hz = np.asarray(freq_hz, dtype=float)
    other_hz = np.asarray(other_hz, dtype=float)
    out = np.zeros(freq_hz.size, dtype=bool)
    if other_hz.size == 0 or freq_hz.size == 0:
        return out
    d = np.abs(other_hz[None, :] - freq_hz[:, None]) / freq_hz[:, None]
    used = np.zeros(other_hz.size, dtype=bool)
    for flat in np.argsort(d, axis=None):
        i, j = np.unravel_index(flat, d.shape)
        if d[i, j] >= rtol:
            break
        if not out[i] and not used[j]:
            out[i] = used[j] = True
    return out


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


def _pseudo_design(frf: FRFData, lam: np.ndarray, theta_x: np.ndarray, ne: int,
                   n_partitions: int) -> np.ndarray:
    """Columns of the step-2 model, (n_lines * n_out * n_in, n_modes), for all roots given."""
    n = frf.n_out
    w = frf.omega[: n_partitions * ne]
    R = -(w[:, None] ** 2) / (1j * w[:, None] - lam[None, :])  # (L, r)
    part = np.arange(n_partitions * ne) // ne
    Dp = np.vstack([np.eye(n)[:, frf.input_index()]] * n_partitions)  # (p n, n_in)
    q = theta_x.T @ Dp  # (r, n_in)
    rows = theta_x.reshape(n_partitions, n, -1)[part]  # (L, n, r)
    return np.einsum("kr,kir,rj->kijr", R, rows, q).reshape(-1, lam.size)


def _pseudo_scale_factors(frf: FRFData, modes, ne: int, n_partitions: int) -> np.ndarray:
    """Least-squares ``1/a~_r`` of the pseudo model's oscillatory pairs (conjugates tied)."""
    m = modes.n_pairs
    lam = modes.lam[: 2 * m]
    th = modes.theta_x[:, : 2 * m]
    E = _pseudo_design(frf, lam, th, ne, n_partitions)
    Et = np.hstack([E[:, :m] + E[:, m:], 1j * (E[:, :m] - E[:, m:])])
    y = frf.H[: n_partitions * ne].reshape(-1)
    v = solve_ls(np.vstack([Et.real, Et.imag]), np.concatenate([y.real, y.imag])[:, None])[:, 0]
    return v[:m] + 1j * v[m:]


def pseudo_dof_fit_error(frf: FRFData, res: PseudoDofResult, structural_only: bool = True) -> float:
    """Relative RMS error of the step-2 pseudo-DOF modal model against the measured FRFs."""
    p = res.n_partitions
    ne = frf.n_freq // p
    keep = res.structural if structural_only else np.ones(res.freq_hz.size, bool)
    lam = np.concatenate([res.lam[keep], res.lam[keep].conj()])
    th = res.theta[: res.theta.shape[0] // 2][:, keep]
    th = np.hstack([th, th.conj()])
    u = np.concatenate([res.u[keep], res.u[keep].conj()])
    Hm = (_pseudo_design(frf, lam, th, ne, p) @ u).reshape(p * ne, frf.n_out, frf.n_in)
    Hd = frf.H[: p * ne]
    return float(np.linalg.norm(Hm - Hd) / np.linalg.norm(Hd))
