"""Frequency-response functions: the measured-data object and synthesis from M, C, K.

Conventions (see ``docs/formats.md``): ``H`` has shape ``(n_freq, n_out, n_in)``; the
quantity is accelerance, (m/s^2)/N; ``omega = 2 pi freq_hz`` in rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import IdentificationError, InputError

__all__ = [
    "FRFData",
    "require_response",
    "require_frequency_dependence",
    "requested_band",
    "receptance",
    "mobility",
    "accelerance",
    "accelerance_from_model",
    "selection_matrix",
    "AppliedLoads",
    "applied_loads",
    "accelerance_under_test_loads",
]


@dataclass
class FRFData:
    """Measured (or synthesised) accelerance FRFs in the contract's FRF-file layout.

    Attributes
    ----------
    freq_hz : (n_freq,) float
        Frequency lines, strictly increasing, > 0.
    H : (n_freq, n_out, n_in) complex
        Acceleration at each output per unit force at each input, (m/s^2)/N.
    outputs : list of str, (n_out,)
        DOF label of each accelerometer.
    inputs : list of str, (n_in,)
        DOF label of each input force; each is also an output.
    coherence : (n_freq, n_out, n_in) float or None
        Ordinary (or multiple) coherence of each value.
    valid : (n_freq, n_out, n_in) bool or None
        False marks a blanked value; it takes part in no fit. None means all valid.
    H_reaction : (n_freq, n_react, n_in) complex or None
        Interface reaction force on the substructure per unit input force, N/N.
    reactions : list of str or None
        DOF label of each reaction; each is also an output.
    H_var : (n_freq, n_out, n_in) float or None
        Variance of each H value, E|H - H_true|^2, when known (e.g. from averages).
    n_avg : int or None
        Number of averages behind each value, when known.
    H_reaction_var : (n_freq, n_react, n_in) float or None
        Variance of each reaction value, (N/N)^2, when known (e.g. from averages).
    """

    freq_hz: np.ndarray
    H: np.ndarray
    outputs: list[str]
    inputs: list[str]
    coherence: np.ndarray | None = None
    valid: np.ndarray | None = None
    H_reaction: np.ndarray | None = None
    reactions: list[str] | None = None
    H_var: np.ndarray | None = None
    n_avg: int | None = None
    H_reaction_var: np.ndarray | None = None
    attrs: dict = field(default_factory=dict)

    @property
    def omega(self) -> np.ndarray:
        """Circular frequency of each line, rad/s, (n_freq,)."""
        return 2.0 * np.pi * np.asarray(self.freq_hz, dtype=float)

    @property
    def n_freq(self) -> int:
        return int(self.H.shape[0])

    @property
    def n_out(self) -> int:
        return int(self.H.shape[1])

    @property
    def n_in(self) -> int:
        return int(self.H.shape[2])

    @property
    def n_react(self) -> int:
        return 0 if self.H_reaction is None else int(self.H_reaction.shape[1])

    def valid_mask(self) -> np.ndarray:
        """Boolean mask (n_freq, n_out, n_in); all True when the file has no ``valid``."""
        if self.valid is None:
            return np.ones(self.H.shape, dtype=bool)
        return np.asarray(self.valid, dtype=bool)

    def input_index(self) -> np.ndarray:
        """Index of each input's DOF among the outputs, (n_in,)."""
        return np.array([self.outputs.index(lbl) for lbl in self.inputs], dtype=int)

    def reaction_index(self) -> np.ndarray:
        """Index of each reaction's DOF among the outputs, (n_react,)."""
        if not self.reactions:
            return np.zeros(0, dtype=int)
        return np.array([self.outputs.index(lbl) for lbl in self.reactions], dtype=int)

    def band(self, f_lo_hz: float, f_hi_hz: float) -> "FRFData":
        """The lines with ``f_lo_hz <= freq_hz <= f_hi_hz`` as a new FRFData."""
        sel = (self.freq_hz >= f_lo_hz) & (self.freq_hz <= f_hi_hz)

        def cut(a):
            return None if a is None else a[sel]

        return replace(
            self,
            freq_hz=self.freq_hz[sel],
            H=self.H[sel],
            coherence=cut(self.coherence),
            valid=cut(self.valid),
            H_reaction=cut(self.H_reaction),
            H_var=cut(self.H_var),
            H_reaction_var=cut(self.H_reaction_var),
        )


# |H| far outside this range is no accelerance in SI units: 1e-100 (m/s^2)/N would take a
# structure of 1e100 kg, and beyond it |H|^2 times omega^4 (the weights and powers the fits
# form) leaves float64 before any physics does.
PLAUSIBLE_ACCELERANCE = (1e-100, 1e100)

# Frequency lines of a vibration test, Hz. Below 1e-6 Hz one period lasts 12 days, longer than
# any test's record; above 1e9 Hz no accelerometer, shaker or force gauge responds. Lines
# outside are a unit or scale error, and far outside the fits break: at 1e-200 Hz omega^2
# underflows to 0 and h / omega^2 is inf; at 1e200 Hz omega^2 overflows. Inside, with |H| in
# PLAUSIBLE_ACCELERANCE, the squares of the regressors h / omega^2 and h omega^2 stay within
# float64 (|H|^2 / omega^4 at 1e100 (m/s^2)/N and 1e-6 Hz is 6e220).
PLAUSIBLE_FREQUENCY_HZ = (1e-6, 1e9)

# Relative change below which an FRF is taken as the same at every line: round-off only.
_CONSTANT_RTOL = 1e-12


def require_response(frf: FRFData, source: str = "FRF data") -> FRFData:
    """Refuse FRFs that no analysis can use: not the FRF layout (:func:`ssid.io.validate_frf`),
    nothing valid, no response, a dead channel or load cell.

    An output DOF whose every valid value is zero (over all inputs and lines) is an
    accelerometer that measured nothing: unwired, dead, or a wrong channel map. An identified
    model, a MAC or a discrepancy over that DOF would be silent garbage, so the analysis
    stops with the channel's name instead. The same holds for an input to which no output
    responds (a shaker that did not drive, or a channel map that points elsewhere), and for
    a reaction that is zero at every line (a dead load cell). A file whose largest |H| lies
    outside :data:`PLAUSIBLE_ACCELERANCE`, or whose lines lie outside
    :data:`PLAUSIBLE_FREQUENCY_HZ`, is refused as a unit or scale error.

    Parameters
    ----------
    frf : FRFData
        The measured FRFs (already checked against the file layout).
    source : str
        Name used at the start of the message (normally the file path).

    Returns
    -------
    FRFData
        The checked data, normalised (:func:`ssid.io.validate_frf`: numpy arrays of float64,
        complex128 and bool, labels as lists of ``str``). An analysis goes on with this copy,
        not with ``frf``: FRFData built in Python may hold lists, which the checks accept and
        the analyses cannot use (``frf.H.shape``).

    Raises
    ------
    InputError
        The first problem found, as one line starting with ``source``.
    """
    # The layout first: FRFData built in Python never went through the file reader, and an input
    # not among the outputs or a NaN not marked invalid would end in an internal error.
    from ssid.io.frf_file import validate_frf  # here: ssid.io imports this module

    frf = validate_frf(frf, source)
    valid = frf.valid_mask()
    if not valid.any():
        raise InputError(f"{source}: every H value is marked invalid: nothing to analyse")
    mag = np.where(valid, np.abs(np.nan_to_num(frf.H)), 0.0)
    largest = float(mag.max())
    if largest == 0.0:
        raise InputError(f"{source}: every H value is zero: no response was measured "
                         "(sensors unwired, or the wrong dataset?)")
    lo, hi = PLAUSIBLE_ACCELERANCE
    if not lo <= largest <= hi:
        raise InputError(f"{source}: the largest |H| is {largest:.3g} (m/s^2)/N, outside "
                         f"{lo:g} to {hi:g}: not an accelerance in SI units (a scale or unit "
                         "error?)")
    f_lo, f_hi = PLAUSIBLE_FREQUENCY_HZ
    first, last = float(frf.freq_hz[0]), float(frf.freq_hz[-1])
    if first < f_lo or last > f_hi:
        raise InputError(f"{source}: the frequency lines run from {first:.3g} to {last:.3g} Hz, "
                         f"outside {f_lo:g} to {f_hi:g} Hz: not the frequencies of a vibration "
                         "test in Hz (a scale or unit error?)")
    for other_axes, labels, kind, what in (
            ((0, 2), frf.outputs, "output", "an accelerometer that measured nothing (unwired or dead?)"),
            ((0, 1), frf.inputs, "input", "no output responded to it (a shaker that did not drive?)")):
        dead = [labels[i] for i in np.flatnonzero(mag.max(axis=other_axes) == 0)]
        if dead:
            raise InputError(
                f"{source}: {_named(kind, dead)} zero or marked invalid at every line: {what}; "
                f"every {kind} DOF must be measured: re-measure it or leave it out of the file")
    if frf.H_reaction is not None and frf.reactions:
        # A reaction read as zero would be taken as a support that holds nothing: the
        # substructure would be identified as free, silently.
        peak = np.abs(frf.H_reaction).max(axis=(0, 2))
        dead = [lbl for lbl, p in zip(frf.reactions, peak) if p == 0]
        if dead:
            raise InputError(f"{source}: {_named('reaction', dead)} zero at every line: a load cell "
                             "that measured nothing (unwired or dead?); re-measure it, or write the "
                             "file without reactions if the support is free there")
    return frf


def requested_band(frf: FRFData, f_min_hz: float | None, f_max_hz: float | None) -> tuple[float, float]:
    """The band ``(lo, hi)`` in Hz an analysis is asked for: ``f_min_hz`` and ``f_max_hz``
    as numbers, the record's first and last line where they are None.

    Raises
    ------
    InputError
        A limit that is not a number (``"abc"``: float's own ValueError said nothing of which
        argument) or not finite (NaN selects no line, and the message would say "between nan
        and nan Hz").
    """
    out = []
    for name, value, default in (("f_min_hz", f_min_hz, frf.freq_hz[0]), ("f_max_hz", f_max_hz, frf.freq_hz[-1])):
        if value is None:
            out.append(float(default))
            continue
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{name} must be a frequency in Hz, got {value!r}") from None
        if not np.isfinite(v):
            raise InputError(f"{name} must be a finite frequency in Hz, got {value!r}")
        out.append(v)
    return out[0], out[1]


def require_frequency_dependence(frf: FRFData, source: str | None = None) -> None:
    """Refuse FRFs that are the same at every line and do not span the outputs: no model fits them.

    SSID finds ``M^-1 C`` and ``M^-1 K`` from how the accelerances change with frequency (they
    multiply ``h / (j omega)`` and ``h / omega^2``, Eq. 3.6). FRFs that do not change at all
    are a mass line alone, ``H = M^-1`` at the measured DOFs. That determines a model only when
    it has full rank over the outputs (a rigid body driven at every DOF, whose K and C are
    zero); of lower rank (fewer inputs than outputs, or outputs that read alike), step 1 has
    no unique solution and its fits fail or return any model (a file whose H was overwritten
    with one constant gave singular matrices, or modes all at 0 Hz).

    Parameters
    ----------
    frf : FRFData
        The FRFs to identify (already accepted by :func:`require_response`).
    source : str, optional
        Name put at the start of the message (the file, where the caller knows it).

    Raises
    ------
    IdentificationError
        The valid values of every FRF are the same at every line (to round-off) and that
        constant matrix has rank below the number of outputs.
    """
    valid = frf.valid_mask()
    lines = np.flatnonzero(valid.any(axis=(1, 2)))
    if lines.size < 2:
        return  # one line: nothing to compare; the fits' own line counts refuse it
    H = np.where(valid, np.nan_to_num(frf.H), 0.0)
    # Each FRF's value at its first valid line, compared with its valid values at the others.
    first = np.argmax(valid, axis=0)  # (n_out, n_in)
    ref = np.take_along_axis(H, first[None], axis=0)[0]
    change = float(np.max(np.where(valid, np.abs(H - ref[None]), 0.0)))
    if change > _CONSTANT_RTOL * float(np.max(np.abs(H))):
        return
    rank = int(np.linalg.matrix_rank(ref))
    if rank < frf.n_out:
        raise IdentificationError(
            ("" if source is None else f"{source}: ")
            + f"H is the same at every frequency line (a mass line alone, of rank {rank} "
            f"for {frf.n_out} outputs): the response does not determine a model (no resonance, "
            "no stiffness or damping in the data; was H overwritten?)")


def _named(kind: str, labels: list[str]) -> str:
    """``"output '4+Z' is"`` or ``"outputs '4+Z', '5+Z' are"``."""
    if len(labels) == 1:
        return f"{kind} {labels[0]!r} is"
    return f"{kind}s {', '.join(map(repr, labels))} are"


def selection_matrix(dofs: list[str], labels: list[str]) -> np.ndarray:
    """0/1 matrix ``S`` (len(dofs), len(labels)) with ``S[i, j] = 1`` where ``dofs[i] == labels[j]``.

    Used as the force distribution matrix D (Eq. 3.1) and as the sensor matrix S.
    """
    index = {lbl: i for i, lbl in enumerate(dofs)}
    S = np.zeros((len(dofs), len(labels)))
    for j, lbl in enumerate(labels):
        S[index[lbl], j] = 1.0
    return S


def receptance(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    omega: np.ndarray,
    D: np.ndarray | None = None,
    S: np.ndarray | None = None,
) -> np.ndarray:
    """Displacement per unit force, ``S (K - omega^2 M + j omega C)^-1 D``.

    Parameters
    ----------
    M, C, K : (n, n)
        Mass, viscous damping (None: undamped) and stiffness matrices.
    omega : (n_freq,)
        Circular frequencies, rad/s.
    D : (n, n_in), optional
        Force distribution matrix (identity when omitted).
    S : (n_out, n), optional
        Sensor selection matrix (identity when omitted).

    Returns
    -------
    (n_freq, n_out, n_in) complex, m/N.
    """
    M = np.asarray(M, dtype=float)
    K = np.asarray(K, dtype=float)
    C = np.zeros_like(M) if C is None else np.asarray(C, dtype=float)
    n = M.shape[0]
    D = np.eye(n) if D is None else np.asarray(D, dtype=float)
    omega = np.asarray(omega, dtype=float)
    # One batched LU solve per line: (n_freq, n, n) dynamic stiffness against (n, n_in) loads.
    Z = K[None] - (omega**2)[:, None, None] * M[None] + 1j * omega[:, None, None] * C[None]
    X = np.linalg.solve(Z, np.broadcast_to(D.astype(complex), (omega.size,) + D.shape))
    if S is not None:
        X = np.einsum("oi,kij->koj", S, X)
    return X


def mobility(M, C, K, omega, D=None, S=None) -> np.ndarray:
    """Velocity per unit force, ``j omega`` times :func:`receptance`, (m/s)/N."""
    return 1j * np.asarray(omega)[:, None, None] * receptance(M, C, K, omega, D, S)


def accelerance(M, C, K, omega, D=None, S=None) -> np.ndarray:
    """Acceleration per unit force, ``-omega^2`` times :func:`receptance`, (m/s^2)/N."""
    return -(np.asarray(omega) ** 2)[:, None, None] * receptance(M, C, K, omega, D, S)


def accelerance_from_model(
    M: np.ndarray,
    C: np.ndarray | None,
    K: np.ndarray,
    dofs: list[str],
    freq_hz: np.ndarray,
    outputs: list[str],
    inputs: list[str],
) -> FRFData:
    """Synthesise an :class:`FRFData` of accelerances of a model at labelled DOFs."""
    freq_hz = np.asarray(freq_hz, dtype=float)
    D = selection_matrix(dofs, inputs)
    S = selection_matrix(dofs, outputs).T
    H = accelerance(M, C, K, 2 * np.pi * freq_hz, D, S)
    return FRFData(freq_hz=freq_hz, H=H, outputs=list(outputs), inputs=list(inputs))


@dataclass(frozen=True)
class AppliedLoads:
    """The forces a test applied to the structure per unit input force.

    Attributes
    ----------
    dofs : list of str
        Load DOFs: the inputs' DOFs, then the reaction DOFs that are not inputs.
    T : (n_freq, n_load, n_in) complex
        Force at load DOF ``l`` per unit force of input ``j``: 1 at the input's own DOF plus,
        on a test stand, the measured interface reactions ``H_reaction[:, r, j]`` at the
        reaction DOFs (the coupling of the report's section 3.3).
    var : (n_freq, n_load, n_in) float or None
        Variance of each entry of ``T`` (the reactions' ``H_reaction_var``; 0 for the unit
        forces), None when the file states none.
    """

    dofs: list[str]
    T: np.ndarray
    var: np.ndarray | None

    def model_accelerance(self, M: np.ndarray, C: np.ndarray | None, K: np.ndarray, dofs: list[str],
                          omega: np.ndarray, outputs: list[str]) -> np.ndarray:
        """A model's accelerance from the load DOFs to ``outputs``, (n_freq, n_out, n_load)."""
        return accelerance(M, C, K, omega, selection_matrix(dofs, self.dofs), selection_matrix(dofs, outputs).T)

    def predict(self, H_model: np.ndarray) -> np.ndarray:
        """``H_model @ T`` line by line: (n_freq, n_out, n_load) -> (n_freq, n_out, n_in)."""
        return np.einsum("kol,kli->koi", H_model, self.T)

    def predicted_variance(self, H_model: np.ndarray) -> np.ndarray | None:
        """Variance the measured reactions' noise gives :meth:`predict`'s values, or None."""
        if self.var is None:
            return None
        return np.einsum("kol,kli->koi", np.abs(H_model) ** 2, self.var)


def applied_loads(frf: FRFData) -> AppliedLoads:
    """What each input of ``frf``'s test applied to the structure (:class:`AppliedLoads`).

    Without reactions in the file, the unit force at each input's DOF alone.
    """
    react = list(frf.reactions or []) if frf.H_reaction is not None else []
    dofs = list(frf.inputs) + [r for r in dict.fromkeys(react) if r not in frf.inputs]
    T = np.zeros((frf.n_freq, len(dofs), frf.n_in), complex)
    T[:, [dofs.index(d) for d in frf.inputs], np.arange(frf.n_in)] = 1.0
    var = None
    if react and frf.H_reaction_var is not None:
        var = np.zeros(T.shape)
    for r, lbl in enumerate(react):
        T[:, dofs.index(lbl), :] += frf.H_reaction[:, r, :]
        if var is not None:
            var[:, dofs.index(lbl), :] += frf.H_reaction_var[:, r, :]
    return AppliedLoads(dofs, T, var)


def accelerance_under_test_loads(M: np.ndarray, C: np.ndarray | None, K: np.ndarray, dofs: list[str],
                                 frf: FRFData) -> np.ndarray:
    """Accelerance a model predicts for a test, under the test's own loads, (n_freq, n_out, n_in).

    Input ``j`` applies a unit force at its DOF; on a test stand the substructure also feels
    the measured interface reactions ``frf.H_reaction[:, :, j]`` at the reaction DOFs (the
    coupling of the report's section 3.3), so the response is ``a_j = H (e_j + D_r r_j)``
    with ``H`` the model's accelerance from the load DOFs (:func:`applied_loads`) to the
    outputs. Without reactions this is the plain accelerance.
    """
    loads = applied_loads(frf)
    return loads.predict(loads.model_accelerance(M, C, K, dofs, frf.omega, frf.outputs))
