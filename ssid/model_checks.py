"""Checks of what the model reductions take (:mod:`ssid.tam`, :mod:`ssid.craig_bampton`) and
of the models whose modes the analyses use: matrices, DOF labels and indices, stability,
elastic modes.

Each refusal is an :class:`ssid.errors.InputError` with a one-line message. :mod:`ssid.tam`
re-exports these names, where they were first defined.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import InputError
from .io import Model, validate_model
from .io._common import _is_whole

__all__ = [
    "RIGID_ROUNDOFF_RTOL",
    "MassNotPositiveDefinite",
    "dof_indices",
    "index_array",
    "model_matrices",
    "n_unstable_modes",
    "omitted_indices",
    "require_elastic_modes",
    "require_stable_stiffness",
]


class MassNotPositiveDefinite(InputError, np.linalg.LinAlgError):
    """M is not positive definite, so (K, M) has no normal modes.

    An InputError for a caller of the public functions (:func:`ssid.tam.normal_modes`), and
    still the ``numpy.linalg.LinAlgError`` that callers wrapping it with their own words
    (which model, what to do) catch.
    """


def model_matrices(M: np.ndarray, K: np.ndarray, source: str = "model") -> tuple[np.ndarray, np.ndarray]:
    """``M`` and ``K`` checked as a model file's are (:func:`ssid.io.validate_model`): real,
    finite, square, of one size and symmetric (to ``ssid.io.SYMMETRY_RTOL`` of the largest
    entry); float64 copies, made exactly symmetric.

    An asymmetric K would be reduced or solved as given by one function and read by its lower
    triangle by another (``eigh``): a model no one wrote. Rows and columns are named by their
    0-based index, as the reductions' DOF indices are.

    Raises
    ------
    InputError
        The first problem found, as one line starting with ``source``.
    """
    n = np.shape(M)[0] if np.ndim(M) >= 1 else 0
    checked = validate_model(Model(M=M, K=K, C=None, dofs=[str(i) for i in range(n)] or ["0"]), source)
    return checked.M, checked.K


def index_array(values: Sequence[int], n: int, what: str = "retained") -> np.ndarray:
    """``values`` as the DOF indices of an ``n``-DOF model, (len,) int.

    Raises
    ------
    InputError
        Not a non-empty 1-D sequence; an index that is not a whole number (0.5 was truncated
        to 0: another DOF, silently), outside ``0..n-1``, or given twice.
    """
    try:
        a = np.asarray(values)
    except ValueError:  # a ragged nesting
        raise InputError(f"{what} must be a non-empty 1-D sequence of DOF indices") from None
    if a.ndim != 1 or a.size == 0:
        raise InputError(f"{what} must be a non-empty 1-D sequence of DOF indices, got shape {a.shape}")
    odd = [v for v in a.tolist() if not _is_whole(v)]
    if odd:
        raise InputError(f"{what} DOF indices must be whole numbers, got {odd[0]!r}")
    idx = a.astype(int)
    out = idx[(idx < 0) | (idx >= n)]
    if out.size:
        raise InputError(f"{what} DOF index {out[0]} is outside 0..{n - 1} (0-based; the model has {n} DOFs)")
    u, count = np.unique(idx, return_counts=True)
    if np.any(count > 1):
        raise InputError(f"{what} DOF index {u[count > 1][0]} is given twice")
    return idx


def dof_indices(dofs: Sequence[str], labels: Sequence[str], what: str = "DOF") -> np.ndarray:
    """Positions of ``labels`` in ``dofs``, (len(labels),) int.

    Raises
    ------
    InputError
        A label is not in ``dofs`` or is given twice.
    """
    where = {lbl: i for i, lbl in enumerate(dofs)}
    out = []
    for lbl in labels:
        if lbl not in where:
            raise InputError(f"{what} {lbl!r} is not among the model's DOFs")
        out.append(where[lbl])
    if len(set(out)) != len(out):
        raise InputError(f"a {what} label is given twice")
    return np.asarray(out, dtype=int)


def omitted_indices(n: int, retained: Sequence[int], what: str = "retained") -> np.ndarray:
    """The o-set: indices ``0..n-1`` not in ``retained``, ascending, (n - n_a,) int.

    ``retained`` is checked by :func:`index_array` (``what`` names it in the message).
    """
    a = index_array(retained, n, what)
    keep = np.ones(n, dtype=bool)
    keep[a] = False
    return np.flatnonzero(keep)


#: ``omega^2`` below 0 by at most this fraction of the largest ``|omega^2|`` is round-off on a
#: rigid-body mode (0 Hz); further below, the model is unstable.
RIGID_ROUNDOFF_RTOL = 1e-8


def n_unstable_modes(lam: np.ndarray) -> int:
    """How many eigenvalues ``omega^2`` of (K, M) (:func:`normal_modes`) are clearly negative:
    modes of an unstable structure, not round-off on rigid-body modes
    (:data:`RIGID_ROUNDOFF_RTOL`)."""
    lam = np.asarray(lam, dtype=float)
    return int(np.sum(lam < -RIGID_ROUNDOFF_RTOL * np.max(np.abs(lam)))) if lam.size else 0


def require_stable_stiffness(lam: np.ndarray, source: str) -> None:
    """Refuse a model with a clearly negative ``omega^2`` (:func:`n_unstable_modes`; ``lam``
    from :func:`normal_modes`): K is not the stiffness of a stable structure, and its modes
    would be read as 0 Hz or as negative frequencies.

    Raises
    ------
    InputError
        Naming ``source`` (the model's file, or "analysis model") and the lowest ``omega^2``.
    """
    if n_unstable_modes(lam):
        raise InputError(f"{source}: K is not positive semi-definite (mode 1 has omega^2 = "
                         f"{lam[0]:.4g} (rad/s)^2): not the stiffness of a stable structure")


def require_elastic_modes(K: np.ndarray, source: str, needed_for: str) -> None:
    """Refuse a model with no elastic mode: K zero, every mode a rigid-body mode at 0 Hz.

    Its modes are then one eigenvalue n times over, and any M-orthonormal basis is a set of
    its mode shapes: what is computed from them (the sensors Effective Independence picks, the
    MAC pairs of a correlation) is an arbitrary choice, not the model's. The discrepancy
    workflow refuses such a model too (:func:`ssid.discrepancy.check_model`), and ``ssidlab
    convert`` refuses to write its modes. A K with a positive eigenvalue (a free-free model's
    elastic modes beside its rigid-body ones) passes; a K that is not positive semi-definite
    is :func:`n_unstable_modes`' to refuse.

    Parameters
    ----------
    K : (n, n)
        Stiffness matrix.
    source : str
        Names the model (its file, or "test model" / "analysis model") in the message.
    needed_for : str
        What the caller would compute from the modes, for the message.

    Raises
    ------
    InputError
        ``K`` is zero.
    """
    if not np.any(np.asarray(K)):
        raise InputError(f"{source}: K is zero: the model has no elastic modes (every mode is a "
                         f"rigid-body mode at 0 Hz, its shapes any basis), so {needed_for} would be "
                         "arbitrary")
