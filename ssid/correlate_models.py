"""Test-analysis correlation studies: a test model or measured FRFs against an analysis model.

:func:`correlate_models` compares an identified (test) model with an analytical one, reducing
the analytical model to the test DOFs with a TAM; :func:`correlate_with_frf` compares an
analytical model with measured FRFs. Both return a :class:`CorrelationStudy` whose ``summary``
is the JSON of ``ssidlab correlate`` (keys in ``docs/correlation.md``) and whose other fields
feed the plots.

Roles: "test" is the identified model or the measured FRFs, "analysis" the analytical model
(full size). Analysis modes are the full model's modes partitioned to the test DOFs (what a
TAM is for: the FEM's shapes, compared with the TAM mass); the TAM's own frequencies are
reported separately (``tam_natural_freq_hz``) as a measure of the TAM's accuracy.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .correlate import MAX_PAIR_FREQ_RATIO, PAIR_REST_RTOL, modes_at_rest
from .correlate_frf import (
    CMIF_REPEATED_MIN_RATIO,
    FRF_GAP_METRIC,
    cmif,
    cmif_modes,
    cmif_shapes,
    frf_assurance,
    frf_gap,
    frf_gap_db,
    refine_peak_frequencies,
)
from .correlate_pairs import MIN_PAIR_MAC, mode_correlation
from .errors import InputError
from .frf import FRFData, requested_band, require_response
from .io import Model
from .reaction_loads import choose_reactions, model_frf_under_loads
from .rigid_body import semi_definite
from .semidefinite_modes import normal_modes_semidefinite
from .tam import (
    _MODE_RCOND,
    RIGID_ROUNDOFF_RTOL,
    TAM_METHODS,
    MassNotPositiveDefinite,
    dof_indices,
    n_unstable_modes,
    reduce_to_tam,
    require_elastic_modes,
    require_stable_stiffness,
    retained_share,
)

__all__ = ["ANALYSIS_BAND_FACTOR", "MAX_PAIR_FREQ_RATIO", "MIN_PAIR_MAC", "PAIR_REST_RTOL", "CorrelationStudy",
           "correlate_models", "correlate_with_frf"]

#: Analysis modes up to this multiple of the highest test frequency take part in the MAC.
ANALYSIS_BAND_FACTOR = 1.5


@dataclass
class CorrelationStudy:
    """Everything a correlation produced: the JSON summary and arrays for the plots."""

    summary: dict
    mac: np.ndarray
    test_freq_hz: np.ndarray
    analysis_freq_hz: np.ndarray
    pairs: list
    frf_test: FRFData | None = None
    frf_model: FRFData | None = None
    cmif_test: np.ndarray | None = None
    cmif_model: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)


def _modes(model: Model, who: str, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Normal modes: frequencies in Hz (a negative omega^2 as a negative frequency) and
    shapes. An analysis model with a clearly negative omega^2 is refused (not a stable
    structure: as ``ssidlab place`` and ``discrepancy`` refuse it); a test model's is said
    in a warning (an identified model that is not physical is still worth correlating).
    Either model with K zero is refused (:func:`ssid.tam.require_elastic_modes`). A model with
    massless DOFs (M positive semi-definite) has its finite modes
    (:func:`ssid.semidefinite_modes.normal_modes_semidefinite`), and ``notes`` says so; an M
    that is indefinite is refused."""
    try:
        lam, phi = normal_modes_semidefinite(model.M, model.K)
    except MassNotPositiveDefinite as exc:
        raise InputError(f"{who} model: {exc}") from None
    if lam.size < model.n:
        notes.append(f"{who} model: M is singular ({model.n - lam.size} massless direction(s), as massless "
                     f"rotations of a lumped-mass model): its {lam.size} finite modes are computed with them "
                     "condensed out statically (exact), the others are at infinite frequency")
    if who == "analysis":
        require_stable_stiffness(lam, "analysis model")
    unstable = n_unstable_modes(lam)
    if unstable:
        warnings.warn(f"{who} model: {unstable} mode(s) with omega^2 < 0 (K not positive "
                      "semi-definite), shown with negative frequencies and not paired unless at rest (a "
                      "rigid-body mode a little below zero)", stacklevel=2)
    # With K zero every mode is at 0 Hz and its shapes are any basis: the MAC, the pairs and
    # the orthogonality checks would be of an arbitrary choice.
    require_elastic_modes(model.K, f"{who} model", "the MAC pairing of its modes")
    return np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi), phi


def _tam(analysis: Model, retained: np.ndarray, tam: str, interface: Sequence[str] | None,
         targets: Sequence[int] | None, test_dofs: Sequence[str]):
    """TAM of the analysis model at ``retained``; ``"none"`` when nothing is omitted."""
    # Interface labels are checked even when no reduction follows: a mistyped one must not
    # pass unnoticed because the analysis model happens to hold only the test DOFs.
    missing = [d for d in interface or [] if d not in test_dofs]
    if missing:
        raise InputError(f"interface DOF {missing[0]!r} is not among the test DOFs")
    if retained.size == analysis.n:
        return "none", analysis.M[np.ix_(retained, retained)], analysis.K[np.ix_(retained, retained)]
    if tam not in TAM_METHODS:
        raise InputError(f"unknown TAM {tam!r}; choose one of {', '.join(TAM_METHODS)}")
    boundary = None
    if interface:
        boundary = dof_indices(analysis.dofs, interface, "interface DOF")
    elif tam == "cb":
        raise InputError("--tam cb needs the interface DOFs (--interface)")
    t0 = None if targets is None else [t - 1 for t in targets]
    try:
        red = reduce_to_tam(tam, analysis.M, analysis.K, retained, targets=t0, boundary=boundary)
    except InputError as exc:  # named as the analysis model's, so that the CLI names its file
        raise InputError(f"analysis model: {exc}") from None
    except np.linalg.LinAlgError as exc:
        raise InputError(f"analysis model: the {tam} reduction failed ({exc})") from None
    return tam, red.M, red.K


def _analysis_band(f_an: np.ndarray, f_test_max: float, n_test: int) -> int:
    """How many analysis modes take part: up to 1.5 x the top test frequency, at least n_test."""
    n = int(np.count_nonzero(f_an <= ANALYSIS_BAND_FACTOR * f_test_max))
    return int(min(f_an.size, max(n, n_test)))


def correlate_models(
    test: Model,
    analysis: Model,
    *,
    tam: str = "guyan",
    interface: Sequence[str] | None = None,
    targets: Sequence[int] | None = None,
) -> CorrelationStudy:
    """Correlate a test (identified) model with an analysis model.

    Parameters
    ----------
    test : Model
        Over the test DOFs; each must be a DOF of ``analysis``.
    analysis : Model
        The analytical model, full size.
    tam : {"guyan", "irs", "serep", "hybrid", "cb"}
        TAM reducing ``analysis`` to the test DOFs (not used when the DOF sets are equal).
    interface : sequence of str, optional
        Interface DOFs (needed by ``cb``).
    targets : sequence of int, optional
        1-based analysis mode numbers: target modes of serep, hybrid and cb.

    Returns
    -------
    CorrelationStudy
    """
    warnings: list[str] = []
    missing = [d for d in test.dofs if d not in set(analysis.dofs)]
    if missing:
        raise InputError(f"test DOF {missing[0]!r} is not among the analysis model's DOFs")
    retained = dof_indices(analysis.dofs, test.dofs)
    tam_used, M_tam, K_tam = _tam(analysis, retained, tam, interface, targets, test.dofs)
    f_test, phi_test = _modes(test, "test", warnings)
    f_all, phi_all = _modes(analysis, "analysis", warnings)
    _rigid_targets_left_out(tam_used, targets, f_all, warnings)
    n_an = _analysis_band(f_all, float(np.max(f_test)), f_test.size)
    f_an, phi_an = f_all[:n_an], _analysis_shapes(phi_all[:, :n_an], retained, warnings)
    f_tam = _tam_frequencies(M_tam, K_tam, warnings)
    corr, mac, pairs = mode_correlation(phi_test, f_test, phi_an, f_an, M_tam, warnings=warnings)
    summary = {
        "mode": "model-model",
        "tam": tam_used,
        "dofs": list(test.dofs),
        "interface_dofs": list(interface or []),
        "target_modes": None if targets is None else [int(t) for t in targets],
        "test_natural_freq_hz": f_test,
        "analysis_natural_freq_hz": f_an,
        "analysis_n_dofs": analysis.n,
        "tam_natural_freq_hz": f_tam,
        **corr,
        "warnings": warnings,
    }
    return CorrelationStudy(summary, mac, f_test, f_an, pairs, warnings=warnings)


def _analysis_shapes(phi: np.ndarray, retained: np.ndarray, warnings: list[str]) -> np.ndarray:
    """The analysis modes ``phi`` (n, m) at the test DOFs, (n_a, m). A mode at rest at every
    test DOF (:func:`ssid.tam.retained_share` at round-off) is given as exact zeros, whose MAC
    is 0 with every test mode, and a warning names it: the MAC, scale-free, would otherwise
    take its round-off (1e-16 of the mode) to unit length and correlate that (0.4-0.6 with the
    test modes of a chain measured at the nodes of its mode 4)."""
    part = phi[retained]
    blind = np.flatnonzero(retained_share(phi, retained) <= _MODE_RCOND)
    if blind.size:
        part = part.copy()
        part[:, blind] = 0.0
        warnings.append(f"analysis mode{'s' if blind.size > 1 else ''} {', '.join(str(k + 1) for k in blind)} "
                        f"{'are' if blind.size > 1 else 'is'} at rest at every test DOF (a node at each): not "
                        "observable by this test, MAC 0 with every test mode")
    return part


def _rigid_targets_left_out(tam_used: str, targets: Sequence[int] | None, f_all: np.ndarray,
                            warnings: list[str]) -> None:
    """Warn when a hybrid TAM's targets (1-based) leave out analysis modes at 0 Hz: the TAM
    moves them off 0 Hz (0.97 and 8.0 Hz on a free beam; :func:`ssid.tam.hybrid_tam`)."""
    if tam_used != "hybrid" or targets is None:
        return
    rigid = [k + 1 for k in np.flatnonzero(modes_at_rest(f_all, RIGID_ROUNDOFF_RTOL)) if k + 1 not in set(targets)]
    if rigid:
        warnings.append(f"the hybrid TAM's target modes leave out analysis mode{'s' if len(rigid) > 1 else ''} "
                        f"{', '.join(map(str, rigid))}, at rest (rigid-body): the TAM moves "
                        f"{'them' if len(rigid) > 1 else 'it'} off 0 Hz, as its projector Phi_ta Phi_ta^T M_m "
                        "does not vanish on a rigid motion and adds the targets' elastic part to it; include "
                        "the modes at rest in the targets")


def _tam_frequencies(M_tam: np.ndarray, K_tam: np.ndarray, warnings: list[str]) -> np.ndarray | None:
    """The TAM's natural frequencies, Hz: its finite ones when its mass is singular and its
    stiffness holds the massless directions (a Guyan TAM at a massless retained DOF)."""
    try:
        lam, _ = normal_modes_semidefinite(M_tam, K_tam)
    except (MassNotPositiveDefinite, InputError):
        warnings.append("the TAM mass is singular (fewer target modes than DOFs?): "
                        "no TAM natural frequencies")
        return None
    if lam.size < np.shape(M_tam)[0]:
        warnings.append(f"the TAM mass is singular ({np.shape(M_tam)[0] - lam.size} massless direction(s)): "
                        f"tam_natural_freq_hz holds its {lam.size} finite frequencies")
    return np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi)


def correlate_with_frf(
    frf: FRFData,
    analysis: Model,
    *,
    tam: str = "guyan",
    interface: Sequence[str] | None = None,
    targets: Sequence[int] | None = None,
    zeta: float = 0.02,
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    reactions: str = "auto",
) -> CorrelationStudy:
    """Correlate an analysis model with measured FRFs.

    The model's accelerances at the FRF's outputs and inputs come from the full model (exact
    at the measured DOFs); with no C in the model, modal damping ``zeta`` is used for every
    mode. FRAC and the gap compare the FRFs; the test "modes" are the CMIF peaks (frequency
    and first left singular vector; at a repeated root also the later curves that peak there,
    :func:`ssid.correlate_frf.cmif_modes`), correlated with the full model's modes at the
    outputs using the TAM mass of ``tam``.

    Parameters
    ----------
    frf : FRFData
    analysis : Model
        Its DOFs include every output of ``frf``.
    zeta : float
        Modal damping ratio used only when ``analysis.C`` is None.
    f_min_hz, f_max_hz : float, optional
        Band of lines compared.
    reactions : {"auto", "apply", "ignore"}
        FRFs measured on a test stand: whether the model is loaded with the measured
        reactions as well as the input force (a model of the substructure alone) or not (a
        model that includes the stand); ``auto`` decides from the data
        (:func:`ssid.reaction_loads.choose_reactions`).
    """
    warnings: list[str] = []
    missing = [d for d in frf.outputs if d not in set(analysis.dofs)]
    if missing:
        raise InputError(f"FRF output {missing[0]!r} is not among the analysis model's DOFs")
    frf = require_response(frf)
    lo, hi = requested_band(frf, f_min_hz, f_max_hz)
    test = frf.band(lo, hi)
    if test.n_freq < 3:
        raise InputError(f"fewer than 3 frequency lines between {lo:g} and {hi:g} Hz (the FRFs "
                         f"cover {frf.freq_hz[0]:g} to {frf.freq_hz[-1]:g} Hz)")
    # The band may hold none of the valid values the whole file has (a blanked stretch):
    # FRAC and gap would be NaN.
    require_response(test, f"FRF data between {lo:g} and {hi:g} Hz")
    valid = test.valid_mask()
    if analysis.C is None:
        from .modal import modal_damping_matrix

        try:
            C = modal_damping_matrix(analysis.M, analysis.K, np.full(analysis.n, zeta))
        except InputError as exc:
            raise InputError(f"analysis model: {exc}") from None
        damping_source = f"modal, zeta = {zeta:g} (the model has no C)"
    else:
        C = analysis.C
        damping_source = "model C"
        if not semi_definite(C):
            warnings.append(f"the analysis model's C has the eigenvalue {np.linalg.eigvalsh(C)[0]:.3g}: it is not a "
                            "damping matrix (some motions would gain energy), and the FRFs FRAC and the gap "
                            "compare with are those of a model that is not passive")
    choice = choose_reactions(analysis.M, C, analysis.K, analysis.dofs, test, reactions)
    model = FRFData(test.freq_hz, model_frf_under_loads(analysis.M, C, analysis.K, analysis.dofs, test, choice.loads),
                    list(test.outputs), list(test.inputs))
    if choice.to_check:
        warnings.append(choice.text)
    if choice.applied:
        warnings.append("the test modes (CMIF peaks) are those of the structure on its stand, the "
                        "analysis modes the model's own: FRAC and the gap compare like with like "
                        "(the model under the measured reactions), the mode pairs do not")
    retained = dof_indices(analysis.dofs, test.outputs)
    tam_used, M_tam, K_tam = _tam(analysis, retained, tam, interface, targets, test.outputs)

    sv_test = cmif(test.H, valid)
    sv_model = cmif(model.H)
    found = cmif_modes(test.freq_hz, sv_test)
    if found.lines.size == 0:
        warnings.append("no CMIF peak in the measured FRFs: no test modes to correlate")
    for f_hz, c, ratio in found.weak:
        db = 20 * np.log10(max(ratio, 1e-300))
        warnings.append(f"CMIF curve {c + 1} also peaks at {f_hz:.4g} Hz, at {db:.0f} dB "
                        f"below curve 1: perhaps a second mode at that frequency, driven weakly; not taken (a "
                        f"mode needs {20 * np.log10(CMIF_REPEATED_MIN_RATIO):.0f} dB or more)")
    f_test = np.array([refine_peak_frequencies(test.freq_hz, sv_test[:, c], [k])[0]
                       for k, c in zip(found.lines, found.curves)], dtype=float)
    phi_test = cmif_shapes(test.H, found.shape_lines, valid, found.curves)
    f_all, phi_all = _modes(analysis, "analysis", warnings)
    _rigid_targets_left_out(tam_used, targets, f_all, warnings)
    n_an = _analysis_band(f_all, float(hi), max(found.lines.size, 1))
    f_an, phi_an = f_all[:n_an], _analysis_shapes(phi_all[:, :n_an], retained, warnings)
    corr, mac, pairs = mode_correlation(phi_test, f_test, phi_an, f_an, M_tam, test_groups=found.groups,
                                        warnings=warnings)
    frac = frf_assurance(test.H, model.H, valid)
    summary = {
        "mode": "model-frf",
        "tam": tam_used,
        "dofs": list(test.outputs),
        "inputs": list(test.inputs),
        "interface_dofs": list(interface or []),
        "target_modes": None if targets is None else [int(t) for t in targets],
        "band_hz": [float(test.freq_hz[0]), float(test.freq_hz[-1])],
        "test_natural_freq_hz": f_test,
        "test_cmif_curve": found.curves + 1,
        "test_freq_source": ("CMIF peaks of the accelerances (parabolic interpolation between lines): for one mode "
                             "at f_n / sqrt(1 - 2 zeta^2), about zeta^2 above its natural frequency"),
        "analysis_natural_freq_hz": f_an,
        "analysis_n_dofs": analysis.n,
        "tam_natural_freq_hz": _tam_frequencies(M_tam, K_tam, warnings),
        **corr,
        "frac": {
            "outputs": list(test.outputs),
            "inputs": list(test.inputs),
            "matrix": frac,
            "mean": float(np.nanmean(frac)),
            "min": float(np.nanmin(frac)),
        },
        "frf_gap": frf_gap(test.H, model.H, valid),
        "frf_gap_metric": FRF_GAP_METRIC,
        "frf_gap_db": frf_gap_db(test.H, model.H, valid),
        "damping_source": damping_source,
        "reactions": choice.to_json_dict(),
        "cmif": {"freq_hz": test.freq_hz, "test": sv_test, "analysis": sv_model},
        "warnings": warnings,
    }
    return CorrelationStudy(summary, mac, f_test, f_an, pairs, test, model, sv_test, sv_model,
                            warnings)
