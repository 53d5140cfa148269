"""Which mass-weighted checks of a correlation mean something.

Orthogonality ``Phi_t^T M Phi_t`` and cross-orthogonality ``Phi_t^T M Phi_a`` (the TAM mass
``M``, shapes at the test DOFs) are judged against the identity. They cannot be met, and say
nothing about the test, when

- there are more shapes than DOFs (or than the rank of ``M``): that many vectors are linearly
  dependent and no inner product makes them orthogonal (the FRFs of a model at 3 outputs gave
  5 CMIF peaks, FRAC 1.000 and a gap of 4e-17, and "fail" with off-diagonal terms of 0.76);
- ``M`` is singular (a SEREP TAM of fewer target modes than DOFs: rank ``n_t``) and a shape
  lies largely outside its range: the mass sees only the shape's projection, scaled up to unit
  modal mass, and a non-target mode of which 10 % lies in the range had a cross-orthogonality
  of 0.991 with itself.

Those checks are reported as not applicable, with their numbers kept.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .correlate import check_orthogonality

__all__ = ["MASS_RANK_RTOL", "TAM_SPAN_MIN_SHARE", "mass_check", "mass_range", "share_in_range"]

#: An eigenvalue of the TAM mass at most this fraction of its largest is zero: a SEREP TAM of
#: n_t targets has the others at round-off (2.6e-16 of the largest on a 3-DOF chain), any
#: physical mass is many decades above.
MASS_RANK_RTOL = 1e-10
#: A shape is inside the TAM mass's range when at least this share of it (the MAC of the shape
#: with its projection on the range) lies there. The checks' bar is a tenth (off-diagonal terms
#: below 0.1): a part outside the range larger than a tenth of the shape's amplitude (a share
#: below 0.99) could meet or fail it by what the mass does not see. A target mode has a share of
#: 1 to round-off, a measured one 1 - (noise)^2; a non-target mode of a 3-DOF chain's SEREP
#: TAM of two targets had 0.10.
TAM_SPAN_MIN_SHARE = 0.99


def mass_range(M: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the range of a symmetric mass, (n, r): the eigenvectors whose
    eigenvalues exceed :data:`MASS_RANK_RTOL` of the largest in magnitude."""
    M = np.asarray(M, dtype=float)
    if M.size == 0:
        return np.zeros((0, 0))
    w, V = np.linalg.eigh((M + M.T) / 2)
    return V[:, w > MASS_RANK_RTOL * max(float(np.max(np.abs(w))), 1e-300)]


def share_in_range(phi: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Share of each shape (column of ``phi``, (n, m), real) inside the span of the orthonormal
    ``basis`` (n, r): ``|P phi|^2 / |phi|^2`` in [0, 1], (m,); 1 for a zero shape."""
    phi = np.asarray(phi, dtype=float)
    size = np.sum(phi**2, axis=0)
    inside = np.sum((basis.T @ phi) ** 2, axis=0)
    return np.where(size > 0, inside / np.where(size > 0, size, 1.0), 1.0)


def mass_check(O: np.ndarray, keep: Sequence[int], rank: int, n_dof: int, what: str, shapes: str,
               diag_min: float) -> tuple[dict, str | None]:
    """A check of a square (paired) orthogonality matrix restricted to its applicable terms.

    Parameters
    ----------
    O : (k, k)
        The matrix (orthogonality of the test modes, or cross-orthogonality of the pairs).
    keep : sequence of int
        0-based positions in ``O`` whose terms apply (both shapes inside the TAM mass's
        range); the same positions on both axes.
    rank, n_dof : int
        Rank of the TAM mass and its size (the number of test DOFs).
    what, shapes : str
        Name of the check and of what its rows are ("test modes", "pairs"), for the note.
    diag_min : float
        As :func:`ssid.correlate.check_orthogonality`.

    Returns
    -------
    dict
        ``min_abs_diag``, ``max_abs_offdiag``, ``worst_offdiag`` (1-based positions in ``O``),
        ``pass`` (None when not applicable), ``status`` ("pass", "fail" or "not applicable"),
        ``not_applicable`` (1-based positions whose terms do not count).
    note : str or None
        Why the check is not applicable as a whole, for the warnings; else None.
    """
    O = np.asarray(O, dtype=float)
    keep = np.asarray(keep, dtype=int)
    note = None
    if keep.size > n_dof:
        note = (f"{keep.size} {shapes} at {n_dof} DOFs: more shapes than DOFs cannot be mass-orthogonal, "
                f"so the {what} check is not applicable (its numbers are kept)")
    elif keep.size > rank:
        note = (f"{keep.size} {shapes} inside the range of a TAM mass of rank {rank}: more shapes than its "
                f"rank cannot be mass-orthogonal, so the {what} check is not applicable (its numbers are kept)")
    elif O.shape[0] and not keep.size:
        note = (f"every one of the {shapes} lies outside the range of the TAM mass (rank {rank} of {n_dof}): "
                f"the {what} check is not applicable")
    if note is not None or not O.shape[0]:  # nothing paired: as check_orthogonality, a fail
        keep = np.arange(O.shape[0])
    chk = check_orthogonality(O[np.ix_(keep, keep)], diag_min=diag_min)
    out = chk.to_dict()
    if chk.worst_offdiag is not None:
        i, j = chk.worst_offdiag
        out["worst_offdiag"] = [int(keep[i]) + 1, int(keep[j]) + 1]
    out["pass"] = None if note else bool(chk.passed)
    out["status"] = "not applicable" if note else ("pass" if chk.passed else "fail")
    out["not_applicable"] = [k + 1 for k in range(O.shape[0]) if note or k not in set(keep.tolist())]
    return out, note
