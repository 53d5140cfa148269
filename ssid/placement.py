"""Sensor placement by Effective Independence (Kammer; report Eq. 6.1).

The Fisher information of the target modes at candidate DOFs is ``F = Phi^T Phi`` (Eq. 6.1).
Effective Independence removes, one at a time, the candidate that contributes least to the
determinant of F: its contribution is the diagonal of the projector
``E = Phi (Phi^T Phi)^-1 Phi^T``. (The report calls this the "Effective Interface" method.)
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .io._common import _is_whole

__all__ = ["SINGULAR_SHAPES_RTOL", "VANISHING_SHAPE_RTOL", "effective_independence",
           "require_observable"]

#: A target whose shape at the candidate DOFs is below this fraction of its norm (over the
#: whole model when given, else of the largest target's at the candidates) is taken as zero
#: there: a mode in a direction the candidates do not measure, whose few values there are
#: the eigensolver's rounding (1e-16 of the shape), not a motion a sensor could see.
VANISHING_SHAPE_RTOL = 1e-9

#: The targets' shapes at the candidates (each scaled to unit norm there) are rank deficient
#: when their smallest singular value is below this fraction of the largest: F = Phi^T Phi
#: then has a condition number above 1/rtol^2 = 2e16, singular in float64 (its determinant,
#: which Effective Independence maximises, is rounding).
SINGULAR_SHAPES_RTOL = 2.0**-26


def require_observable(phi: np.ndarray, mode_names: list | None = None,
                       mode_norms: np.ndarray | None = None) -> None:
    """Refuse target shapes that no choice of the candidate DOFs can tell apart.

    Effective Independence maximises the determinant of the Fisher information
    ``F = Phi^T Phi`` (Eq. 6.1). When a target vanishes at every candidate (a mode in a
    direction they do not measure: X modes and Z accelerometers), or the targets' shapes
    there are otherwise linearly dependent, F is singular for every choice: its determinant
    is 0 (or rounding), so the choice means nothing, the auto-MAC of a zero shape is 0 (read
    as "perfectly told apart") and the condition of F is infinite.

    Parameters
    ----------
    phi : (n_cand, n_modes)
        Target shapes at the candidate DOFs.
    mode_names : list, optional
        How to name each target in the message (default: its column, 1-based).
    mode_norms : (n_modes,), optional
        Each target shape's norm over the whole model, so that "vanishes at the candidates"
        is judged against the mode itself (default: the largest target's norm at the
        candidates, for shapes of comparable scale, e.g. mass-normalised).

    Raises
    ------
    InputError
        Naming the targets that vanish at every candidate (:data:`VANISHING_SHAPE_RTOL`), or
        else the rank of the shapes (:data:`SINGULAR_SHAPES_RTOL`).
    """
    phi = np.asarray(phi, dtype=float)
    n_cand, n_modes = phi.shape
    names = [str(k + 1) for k in range(n_modes)] if mode_names is None else list(mode_names)
    norms = np.linalg.norm(phi, axis=0)
    ref = np.max(norms) if mode_norms is None else np.asarray(mode_norms, dtype=float)
    zero = norms <= VANISHING_SHAPE_RTOL * ref
    if zero.any():
        which = [names[k] for k in np.flatnonzero(zero)]
        raise InputError(
            f"target mode{'s' if len(which) > 1 else ''} {', '.join(which)} "
            f"vanish{'es' if len(which) == 1 else ''} at every candidate DOF: no sensor there "
            f"observes {'it' if len(which) == 1 else 'them'}, the Fisher information F = Phi^T Phi is "
            "singular and Effective Independence has no meaning; choose candidates that move in those "
            "modes, or other targets")
    sv = np.linalg.svd(phi / norms, compute_uv=False)
    rank = int(np.count_nonzero(sv > SINGULAR_SHAPES_RTOL * sv[0]))
    if rank < n_modes:
        raise InputError(
            f"the {n_modes} target modes' shapes at the {n_cand} candidate DOFs have rank {rank}: "
            "no choice of these DOFs tells them apart (the Fisher information F = Phi^T Phi is "
            "singular and Effective Independence has no meaning); add candidates that do, or "
            "drop targets")


def effective_independence(
    phi: np.ndarray, n_keep: int, candidates: list[str] | None = None,
    required: list | None = None, mode_names: list | None = None,
    mode_norms: np.ndarray | None = None,
) -> list:
    """Keep ``n_keep`` of the candidate DOFs that best observe the target modes.

    Parameters
    ----------
    phi : (n_cand, n_modes) or (n_cand,)
        Target mode shapes at the candidate DOFs (any scaling: E is scale-invariant per mode);
        a 1-D array is one mode.
    n_keep : int
        Number of DOFs to keep, a whole number; at least ``n_modes`` (F must stay invertible)
        and at most ``n_cand``.
    candidates : list, optional
        Labels of the candidate rows (default: row indices).
    required : list, optional
        Candidates (labels, or indices without ``candidates``) that are always kept, e.g. the
        driving points and interface DOFs a test must measure: they are never removed, and
        the others are chosen to complement them.
    mode_names, mode_norms : optional
        As for :func:`require_observable`, which refuses targets the candidates cannot
        observe.

    Returns
    -------
    The kept labels (or indices), in the candidates' original order.

    Raises
    ------
    InputError
        Shapes that are not finite numbers (all NaN, the QR below picked DOFs anyway), an
        ``n_keep`` that is not a whole number (4.5 kept 4) or outside ``n_modes..n_cand``, a
        required DOF that is no candidate or more of them than ``n_keep``, targets that the
        candidates cannot observe (:func:`require_observable`: F singular for every choice).
        With shapes of full rank at the candidates the choice keeps that rank: a DOF whose
        removal would lose it has ``E_ii = 1``, and one below 1 is always there to remove.
    """
    phi = np.asarray(phi)
    if phi.ndim == 1:
        phi = phi[:, None]
    if phi.ndim != 2 or phi.dtype.kind not in "iuf":
        raise InputError(f"phi must be real mode shapes, (candidates, modes), got {phi.dtype} of shape {phi.shape}")
    if not np.isfinite(phi).all():
        raise InputError(f"phi holds NaN or Inf in {int(np.count_nonzero(~np.isfinite(phi)))} value(s): "
                         "no sensor can be chosen from such mode shapes")
    phi = phi.astype(float)
    n_cand, n_modes = phi.shape
    if not _is_whole(n_keep):
        raise InputError(f"n_keep must be a whole number of sensors, got {n_keep!r}")
    n_keep = int(n_keep)
    if not n_modes <= n_keep <= n_cand:
        raise InputError(f"n_keep must lie between the number of modes ({n_modes}) and of "
                         f"candidates ({n_cand}), got {n_keep}")
    labels = list(range(n_cand)) if candidates is None else list(candidates)
    fixed = np.zeros(n_cand, dtype=bool)
    for r in required or []:
        if r not in labels:
            raise InputError(f"required DOF {r!r} is not a candidate")
        fixed[labels.index(r)] = True
    if fixed.sum() > n_keep:
        raise InputError(f"{int(fixed.sum())} required DOFs, more than the {n_keep} to keep")
    require_observable(phi, mode_names, mode_norms)
    keep = np.arange(n_cand)
    while keep.size > n_keep:
        # Diagonal of the projector by QR: E_ii = |Q_i|^2, stable even when F is ill-conditioned.
        q, _ = np.linalg.qr(phi[keep])
        e = np.where(fixed[keep], np.inf, np.sum(q * q, axis=1))
        keep = np.delete(keep, int(np.argmin(e)))
    return [labels[i] for i in keep]
