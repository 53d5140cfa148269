"""Modes that share a frequency, compared as subspaces.

A repeated natural frequency (a symmetric structure's pairs, a free body's rigid-body modes)
has an eigenspace, not modes: any orthonormal combination of its modes is as much a set of
its modes as the one an eigensolver or an identification happened to return. Compared one by
one, two exact sets of such modes give MACs and cross-orthogonality terms of an arbitrary
rotation (a free-free beam's rigid-body modes against themselves: MAC 0.79 and 0.87, the
cross-orthogonality block ``[[0.41, -0.91], [0.91, 0.41]]``). Here the modes of each set
that share a frequency are grouped (:func:`frequency_groups`); where a test group meets an
analysis group, the test modes are rotated within their own span to match the analysis
modes (:func:`compare_subspaces`), and the principal angles between the two spans say how
alike the spaces are, whatever the basis.

Shapes are columns at the test DOFs, ``(n_dof, n_modes)``; frequencies in Hz, signed as
:func:`ssid.tam.natural_frequencies_hz` gives them (negative for omega^2 < 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy.optimize import linear_sum_assignment

from .correlate import (
    modal_assurance,
    modes_at_rest,
    normalize_modal_mass,
    real_mode_from_complex,
)
from .correlate_scope import share_in_range
from .model_checks import RIGID_ROUNDOFF_RTOL

__all__ = ["REPEATED_FREQ_RTOL", "Subspace", "compare_subspaces", "frequency_groups", "procrustes_rotation"]

#: Elastic modes of one set whose natural frequencies differ by at most this fraction share a
#: frequency: their basis is noise, and they are compared as a subspace. Two modes split by
#: 2e-4 (0.02 %) lie within each other's half-power band unless the damping is below 0.02 %,
#: less than almost any built structure's, and a record that separates them by its lines is
#: 5000 / f seconds long (500 s at 10 Hz); an identification that returns them so split gives
#: their frequencies, not a basis one can hold against a model's. The bound is a cliff: a pair
#: split by 1.99e-4 is compared as a subspace and one split by 2.01e-4 mode by mode, and the
#: verdict can change at this split (a model whose pairs lie along axes turned by 45 degrees
#: from the test's: MAC 1 and a pass below, MAC 0.5 and a fail above). Modes whose half-power
#: bands overlap are not grouped on that ground: with several references an identification
#: resolves them, and rotating them onto the model's would hide a real mixing of the shapes,
#: which is what a test engineer looks for. The bound before, 1e-6, was as much a cliff, where
#: nothing is resolved on either side (a split of 0.5e-6 passed, one of 2e-6 failed).
REPEATED_FREQ_RTOL = 2e-4


def frequency_groups(f_hz: np.ndarray, rtol: float = REPEATED_FREQ_RTOL) -> list[np.ndarray]:
    """Groups of two or more modes of one set that share a frequency, 0-based indices.

    The modes at rest to round-off (:func:`ssid.correlate.modes_at_rest` with
    ``ssid.model_checks.RIGID_ROUNDOFF_RTOL``, rigid-body modes) are one group;
    elastic modes (omega^2 > 0, not at rest) form a group when each is within ``rtol`` of the
    next in frequency. A mode with omega^2 < 0 that is not at rest belongs to no group (no
    mode of a structure). Groups are in ascending order of their first mode.

    Parameters
    ----------
    f_hz : (n,)
        Natural frequencies, Hz, signed.

    Returns
    -------
    list of (n_g,) int arrays, each ascending.
    """
    f = np.asarray(f_hz, dtype=float)
    # At rest to round-off, not to the pairing's looser bound (PAIR_REST_RTOL, frequencies up to
    # 1e-3 of the set's highest): under it a free beam's bounce and pitch on bungees, 0.46 and
    # 1.06 Hz in a 2 kHz band, were one "repeated root" and rotated onto a model's 0.61 and
    # 1.06 Hz modes in the other order: MAC 1.000 for modes 73 % apart.
    rest = modes_at_rest(f, RIGID_ROUNDOFF_RTOL)
    groups = [np.flatnonzero(rest)] if np.count_nonzero(rest) > 1 else []
    elastic = np.flatnonzero(~rest & (f > 0))
    elastic = elastic[np.argsort(f[elastic], kind="stable")]
    run: list[int] = []
    for k in elastic:
        if run and f[k] - f[run[-1]] > rtol * f[k]:
            if len(run) > 1:
                groups.append(np.sort(np.asarray(run)))
            run = []
        run.append(int(k))
    if len(run) > 1:
        groups.append(np.sort(np.asarray(run)))
    return sorted(groups, key=lambda g: int(g[0]))


def procrustes_rotation(phi_t: np.ndarray, phi_a: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Orthogonal ``Q`` (m_t, m_t) that turns ``phi_t`` within its span towards ``phi_a``.

    The first ``min(m_t, m_a)`` columns of ``phi_t @ Q`` match the columns of ``phi_a`` in
    order: ``Q`` maximises ``trace(Q^T phi_t^T W phi_a)`` (orthogonal Procrustes with the
    weight ``W``); with ``m_t > m_a`` the remaining columns span what of ``phi_t`` is left.

    Parameters
    ----------
    phi_t : (n, m_t)
        Shapes to rotate, real, as they are scaled (their rotation keeps their own
        orthonormality, in whatever inner product they have it).
    phi_a : (n, m_a)
        Target shapes, real, with ``m_a <= m_t``; scaled to unit modal mass in ``W`` here.
    W : (n, n)
        Weight (the TAM mass, or the identity).
    """
    phi_a = normalize_modal_mass(phi_a, W)
    A = phi_t.T @ W @ phi_a
    U, _, Vt = np.linalg.svd(A, full_matrices=True)
    m_a = phi_a.shape[1]
    Q = U.copy()
    Q[:, :m_a] = U[:, :m_a] @ Vt
    return Q


@dataclass
class Subspace:
    """Test modes and an analysis group sharing a frequency, compared as subspaces.

    Attributes
    ----------
    test, analysis : (n_t,), (n_a,) int
        0-based mode numbers: a test group and an analysis group (``rotated`` "test"), or an
        analysis group and the distinct test modes it was rotated onto ("analysis").
    aligned_with : (min(n_t, n_a),) int
        What the rotated modes were turned towards, in order: with ``rotated`` "test" the
        analysis modes (with more analysis than test modes those best represented in the
        test span), with "analysis" the test modes.
    at_rest : bool
        The analysis group (and a rotated test group) are modes at rest (rigid-body modes).
    angles_deg : (min(n_t, n_a),) float
        Principal angles between the spans at the test DOFs (unweighted, as the MAC),
        ascending, degrees: 0 for one space.
    rotation : (n_t, n_t) or (n_a, n_a)
        Orthogonal ``Q``: rotated modes = ``phi[:, group] @ Q`` of the side ``rotated``.
    weighting : str
        Inner product of the rotation.
    mac_before : (n_t, n_a)
        MAC of the test modes with the analysis group, before the rotation.
    rotated : {"test", "analysis"}
        Which side's modes were rotated.
    """

    test: np.ndarray
    analysis: np.ndarray
    aligned_with: np.ndarray
    at_rest: bool
    angles_deg: np.ndarray
    rotation: np.ndarray
    weighting: str
    mac_before: np.ndarray
    rotated: str = "test"

    def to_dict(self) -> dict:
        return {
            "rotated": self.rotated,
            "test_modes": [int(k) + 1 for k in self.test],
            "analysis_modes": [int(k) + 1 for k in self.analysis],
            "aligned_with": [int(k) + 1 for k in self.aligned_with],
            "at_rest": bool(self.at_rest),
            "principal_angles_deg": self.angles_deg,
            "rotation": self.rotation,
            "weighting": self.weighting,
            "mac_before_rotation": self.mac_before,
        }


def compare_subspaces(
    phi_test: np.ndarray, f_test: np.ndarray, phi_an: np.ndarray, f_an: np.ndarray,
    M_tam: np.ndarray, admissible: np.ndarray, min_score: float,
    test_groups: Sequence[Sequence[int]] | None = None,
) -> tuple[np.ndarray, np.ndarray, list[Subspace]]:
    """Rotate the modes of a group sharing a frequency within their span, where they meet
    modes of the other set.

    Groups (:func:`frequency_groups`, or ``test_groups`` for test modes known to share a
    frequency, as the CMIF curves of one peak) of two or more modes on both sides are matched
    one to one (Hungarian) on the mean squared cosine of their principal angles, among the
    pairs of groups the pairing rule admits (``admissible`` for every member) with a mean of
    at least ``min_score`` (the MAC a pair needs: the same bar for a space as for a mode).
    The test modes of a matched group are rotated within their span onto the analysis modes
    (:func:`procrustes_rotation`).

    Test modes whose frequencies are split are distinct modes and are never rotated. Where an
    analysis group that no test group matched meets such test modes (a free-free model's
    rigid-body modes and the suspension modes a test on bungees measures, at 1.06 and 1.84
    Hz: in the eigensolver's basis the bounce mode had MAC 0.44 with everything and was not
    paired), it is the analysis modes, an arbitrary basis of their root, that are rotated
    onto the test modes: those (not otherwise rotated, admitted by the pairing rule) with at
    least ``min_score`` of their shape in the analysis span and no better match outside it,
    the best represented first, at most as many as the group has modes.

    Why an orthogonal rotation weighted with the TAM mass: a rotation of a repeated root's
    modes gives modes of that root again, orthogonal and of unit modal mass as before, so the
    result is re-expressed, not changed; a least-squares fit (any matrix) would also stretch
    and shear one space towards the other and make up agreement the test does not show.
    Weighted with the TAM mass it maximises the sum of the group's paired cross-orthogonality
    terms, the quantity the criterion checks. When the TAM mass is not positive definite (a
    SEREP TAM of fewer target modes than DOFs) it cannot weigh every direction, and the
    rotation is unweighted (the MAC's inner product).

    Parameters
    ----------
    phi_test : (n, m_t), real or complex; f_test : (m_t,) Hz
    phi_an : (n, m_a) real; f_an : (m_a,) Hz
    M_tam : (n, n)
    admissible : (m_t, m_a) bool
        Which pairs the pairing rule allows.
    min_score : float
    test_groups : sequence of sequences of int, optional
        0-based; default ``frequency_groups(f_test)``.

    Returns
    -------
    phi_test : (n, m_t)
        The test shapes, each rotated group's columns replaced (real there).
    phi_an : (n, m_a)
        The analysis shapes, each rotated group's columns replaced.
    subspaces : list of Subspace
    """
    groups_t = [np.asarray(g, dtype=int) for g in (frequency_groups(f_test) if test_groups is None
                                                   else test_groups) if len(g) > 1]
    groups_a = frequency_groups(f_an)
    out_t = np.array(phi_test, copy=True)
    out_a = np.array(phi_an, dtype=float, copy=True)
    if not groups_a:
        return out_t, out_a, []
    real_t = real_mode_from_complex(phi_test)
    score = np.zeros((len(groups_t), len(groups_a)))
    for i, g in enumerate(groups_t):
        for j, h in enumerate(groups_a):
            if admissible[np.ix_(g, h)].all() and _has_motion(real_t[:, g]) and _has_motion(out_a[:, h]):
                score[i, j] = np.mean(np.cos(sla.subspace_angles(real_t[:, g], out_a[:, h])) ** 2)
    W, weighting = _weight(M_tam)
    rest_t, rest_a = modes_at_rest(f_test, RIGID_ROUNDOFF_RTOL), modes_at_rest(f_an, RIGID_ROUNDOFF_RTOL)
    found, used_a, rotated_t = [], set(), set()
    for i, j in zip(*linear_sum_assignment(score, maximize=True)) if score.size else ():
        if score[i, j] < min_score:
            continue
        g, h = groups_t[i], groups_a[j]
        pt, pa = real_t[:, g], out_a[:, h]
        sel = h if h.size <= g.size else h[np.sort(np.argsort(-_captured(pt, pa), kind="stable")[:g.size])]
        Q = procrustes_rotation(pt, out_a[:, sel], W)
        out_t = out_t.astype(np.result_type(out_t, float))
        out_t[:, g] = pt @ Q
        found.append(Subspace(g, h, sel, bool(rest_t[g].all() and rest_a[h].all()), _angles(pt, pa), Q,
                              weighting, modal_assurance(pt, pa)))
        used_a.add(j)
        rotated_t.update(g.tolist())
    for j, h in enumerate(groups_a):
        pa = out_a[:, h]
        if j in used_a or not _has_motion(pa):
            continue
        # Test modes the group's span holds at least as well as any analysis mode outside it
        # holds them: a tower's 6.3 Hz test mode has 0.64 of itself in the span of the 9.1 Hz
        # pair, but MAC 1 with a 6.3 Hz mode.
        others = np.setdiff1d(np.arange(out_a.shape[1]), h)
        elsewhere = modal_assurance(real_t, out_a[:, others]).max(axis=1) if others.size else np.zeros(real_t.shape[1])
        within = _captured(pa, real_t)
        free = np.array([i for i in range(real_t.shape[1]) if i not in rotated_t and admissible[i, h].all()
                         and within[i] >= elsewhere[i]], dtype=int)
        share = within[free]
        best = np.argsort(-share, kind="stable")[: h.size]
        keep = np.sort(free[best][share[best] >= min_score])
        if not keep.size:
            continue
        pt = real_t[:, keep]
        Q = procrustes_rotation(pa, pt, W)
        out_a[:, h] = pa @ Q
        found.append(Subspace(keep, h, keep, bool(rest_a[h].all()), _angles(pt, pa), Q, weighting,
                              modal_assurance(pt, pa), rotated="analysis"))
    return out_t, out_a, sorted(found, key=lambda s: (int(s.test[0]), s.rotated))


def _angles(pt: np.ndarray, pa: np.ndarray) -> np.ndarray:
    """Principal angles between two spans, degrees, ascending."""
    return np.sort(np.degrees(sla.subspace_angles(pt, pa)))


def _has_motion(phi: np.ndarray) -> bool:
    """Every column nonzero: a span of zero shapes (modes at rest at every test DOF) has no angles."""
    return bool(np.all(np.linalg.norm(phi, axis=0) > 0))


def _captured(pt: np.ndarray, pa: np.ndarray) -> np.ndarray:
    """Share of each column of ``pa`` inside the span of ``pt`` (its MAC with its projection;
    0 for a zero column)."""
    return np.where(np.any(pa != 0, axis=0), share_in_range(pa, np.linalg.qr(pt)[0]), 0.0)


def _weight(M_tam: np.ndarray) -> tuple[np.ndarray, str]:
    """The TAM mass when it is positive definite, else the identity (and which, in words)."""
    M = np.asarray(M_tam, dtype=float)
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return np.eye(M.shape[0]), "unweighted (the TAM mass is not positive definite)"
    return M, "TAM mass"
