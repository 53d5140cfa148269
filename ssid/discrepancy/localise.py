"""Localisation: how much of the measured-minus-model residual a change at each DOF can explain.

For a change ``delta_k u u^T`` of the dynamic stiffness at line ``k`` the model FRFs move by
``-a_k P_k`` (``ssid.discrepancy.response``), a fixed spatial pattern ``P_k`` (n_out, n_in) times
one complex number ``a_k``. Whatever the effect's frequency dependence, the weighted residual
``R = H_meas - H_nom`` left after it is

    chi2(a) = chi2_0 - E + sum_k c_k |a_k - a*_k|^2,
    c_k = sum W^2 |P_k|^2,   b_k = sum W^2 conj(P_k) R_k,   a*_k = -b_k / c_k,
    E = sum_k |b_k|^2 / c_k.

So each candidate location is summarised by three numbers per line (``c``, ``a*`` and
``g = u^T G u``), exactly: fitting any effect there is a fit of ``a(theta)`` to ``a*`` with
weights ``c`` (``ssid.discrepancy.fit``), and ``E`` is the most that *any* one change at that
location can remove from ``chi2_0`` -- the localisation measure, and an exact bound used to
skip locations that cannot win.

``a*`` also gives the "measured" dynamic-stiffness change at the location,
``delta*_k = a*_k / (1 - a*_k g_k)``: ``-omega^2 m`` for a mass, a constant for a spring,
``j omega c`` for a damper, a resonance for an attached oscillator (plotted in the report).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .response import NominalResponse

__all__ = ["Locations", "candidate_pairs", "compress", "pair_locations", "single_dof_locations"]


@dataclass
class Locations:
    """Compressed residual data of a set of candidate locations (single DOFs or DOF pairs).

    Attributes
    ----------
    index : (n_loc, 2) int
        Model DOF indices ``(p, q)``; ``q = -1`` for a single DOF (``u = e_p``), else
        ``u = e_p - e_q``.
    c : (n_freq, n_loc) float
        ``sum W^2 |P|^2`` per line (0 where no valid value sees the location).
    astar : (n_freq, n_loc) complex
        Free per-line coefficient ``a*`` (0 where ``c`` is 0).
    g : (n_freq, n_loc) complex
        ``u^T G u`` of the nominal model.
    explained : (n_loc,) float
        ``E = sum c |a*|^2``: the largest decrease of ``chi2`` (weighted complex sum of
        squares) that one change at the location can give.
    """

    index: np.ndarray
    c: np.ndarray
    astar: np.ndarray
    g: np.ndarray
    explained: np.ndarray

    @classmethod
    def from_cb(cls, index, c: np.ndarray, b: np.ndarray, g: np.ndarray) -> Locations:
        """From ``c`` and ``b = sum W^2 conj(P) R`` per line: ``a* = -b / c`` where ``c > 0``."""
        seen = c > 1e-300 * max(float(c.max(initial=0.0)), 1e-300)
        c = np.where(seen, c, 0.0)
        astar = np.where(seen, -b / np.where(seen, c, 1.0), 0)
        return cls(np.asarray(index, dtype=int), c, astar, g, np.sum(c * np.abs(astar) ** 2, axis=0))

    @property
    def n(self) -> int:
        return int(self.index.shape[0])

    def subset(self, sel: np.ndarray) -> Locations:
        return Locations(self.index[sel], self.c[:, sel], self.astar[:, sel], self.g[:, sel],
                         self.explained[sel])

    def lines(self, sel: np.ndarray) -> Locations:
        """The same locations restricted to the lines ``sel`` (mask or indices), ``E`` recomputed."""
        c, ast = self.c[sel], self.astar[sel]
        return Locations(self.index, c, ast, self.g[sel], np.sum(c * np.abs(ast) ** 2, axis=0))

    def delta_star(self, j: int) -> np.ndarray:
        """Measured dynamic-stiffness change at location ``j``, (n_freq,) complex, NaN where unseen."""
        a = self.astar[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            d = a / (1 - a * self.g[:, j])
        return np.where(self.c[:, j] > 0, d, np.nan)


def compress(omega: np.ndarray, g_o: np.ndarray, g_i: np.ndarray, W2: np.ndarray,
              W2R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c`` and ``b`` of patterns ``P = -w^2 g_o g_i^T`` at every line and location.

    g_o : (n_freq, n_out, n_loc); g_i : (n_freq, n_loc, n_in); W2, W2R : (n_freq, n_out, n_in).
    """
    w2 = omega**2
    # sum_oi W2 |g_o|^2 |g_i|^2 as two batched products (n_freq, n_out, n_loc).
    T1 = W2 @ np.abs(g_i).transpose(0, 2, 1) ** 2
    c = (w2**2)[:, None] * np.sum(np.abs(g_o) ** 2 * T1, axis=1)
    T2 = W2R @ np.conj(g_i).transpose(0, 2, 1)
    b = -w2[:, None] * np.sum(np.conj(g_o) * T2, axis=1)
    return c, b


def single_dof_locations(nom: NominalResponse, W: np.ndarray, R: np.ndarray,
                         dofs: np.ndarray | None = None) -> Locations:
    """Locations ``u = e_p`` for the model DOFs ``dofs`` (default: all).

    Parameters
    ----------
    nom : NominalResponse
    W : (n_freq, n_out, n_in)
        Weights (0 where not valid).
    R : (n_freq, n_out, n_in)
        Residual ``H_meas - H_nom`` (any value where ``W`` is 0).
    """
    n = nom.G_diag.shape[1]
    p = np.arange(n) if dofs is None else np.asarray(dofs, dtype=int)
    W2 = W**2
    W2R = W2 * np.where(W > 0, R, 0)
    c, b = compress(nom.omega, nom.G_out[:, :, p], nom.G_in[:, p, :], W2, W2R)
    index = np.column_stack([p, np.full(p.size, -1)])
    return Locations.from_cb(index, c, b, nom.G_diag[:, p])


def pair_locations(nom: NominalResponse, W: np.ndarray, R: np.ndarray, pairs: np.ndarray,
                   G_pq: np.ndarray, G_qp: np.ndarray) -> Locations:
    """Locations ``u = e_p - e_q`` for ``pairs`` (m, 2), given ``G[p, q]`` and ``G[q, p]`` (n_freq, m)."""
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    p, q = pairs[:, 0], pairs[:, 1]
    W2 = W**2
    W2R = W2 * np.where(W > 0, R, 0)
    g_o = nom.G_out[:, :, p] - nom.G_out[:, :, q]
    g_i = nom.G_in[:, p, :] - nom.G_in[:, q, :]
    c, b = compress(nom.omega, g_o, g_i, W2, W2R)
    g = nom.G_diag[:, p] + nom.G_diag[:, q] - G_pq - G_qp
    return Locations.from_cb(pairs, c, b, g)


def candidate_pairs(K: np.ndarray, ranked_dofs: np.ndarray, n_top: int = 6,
                    max_pairs: int = 2000) -> np.ndarray:
    """DOF pairs ``(p, q)``, ``p < q``, where a coupling spring is tried, (m, 2).

    A joint acts between DOFs that the structure already connects, so the pairs are those
    with ``K[p, q] != 0`` (relative to ``sqrt(K_pp K_qq)``, above round-off), plus every pair
    among the ``n_top`` best-localised DOFs (``ranked_dofs``, best first) in case the joint
    is new. A dense K (a reduced model) could give ``n^2/2`` pairs; beyond ``max_pairs`` those
    whose DOFs rank best are kept.
    """
    n = K.shape[0]
    d = np.sqrt(np.abs(np.diag(K)))
    scale = np.outer(d, d)
    iu, ju = np.triu_indices(n, 1)
    linked = np.abs(K[iu, ju]) > 1e-9 * np.where(scale[iu, ju] > 0, scale[iu, ju], np.inf)
    pairs = {(int(a), int(b)) for a, b in zip(iu[linked], ju[linked])}
    top = [int(x) for x in ranked_dofs[:n_top]]
    for i, a in enumerate(top):
        for b in top[i + 1:]:
            pairs.add((min(a, b), max(a, b)))
    out = np.array(sorted(pairs), dtype=int).reshape(-1, 2)
    if out.shape[0] > max_pairs:
        rank = np.full(n, n, dtype=int)
        rank[np.asarray(ranked_dofs, dtype=int)] = np.arange(len(ranked_dofs))
        order = np.argsort(rank[out[:, 0]] + rank[out[:, 1]], kind="stable")
        out = out[np.sort(order[:max_pairs])]
    return out
