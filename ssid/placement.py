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

__all__ = ["effective_independence"]


def effective_independence(
    phi: np.ndarray, n_keep: int, candidates: list[str] | None = None,
    required: list | None = None,
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

    Returns
    -------
    The kept labels (or indices), in the candidates' original order.

    Raises
    ------
    InputError
        Shapes that are not finite numbers (all NaN, the QR below picked DOFs anyway), an
        ``n_keep`` that is not a whole number (4.5 kept 4) or outside ``n_modes..n_cand``, a
        required DOF that is no candidate or more of them than ``n_keep``.
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
    keep = np.arange(n_cand)
    while keep.size > n_keep:
        # Diagonal of the projector by QR: E_ii = |Q_i|^2, stable even when F is ill-conditioned.
        q, _ = np.linalg.qr(phi[keep])
        e = np.where(fixed[keep], np.inf, np.sum(q * q, axis=1))
        keep = np.delete(keep, int(np.argmin(e)))
    return [labels[i] for i in keep]
