"""The physics world behind every simulated instrument.

Chain: generator voltage -> amplifier (gain, enable, protection) -> electrodynamic shaker
(armature, suspension, coil with back-EMF, stinger) -> structure (any M, C, K with hidden
effects, optionally on a flexible test stand) -> sensors (sensitivity, noise floor, range)
-> the DAQ front end's anti-alias filter (at the internal step, when there are several per
sample). The DAQ simulator digitises the sensor voltages (range, coupling, quantisation).

Time integration
----------------
The mechanical and electrical parts form one linear state-space system
``z' = A z + B u`` (``u``: amplifier output voltages). It is diagonalised once,
``A = V diag(lambda) V^-1``, and each mode is discretised exactly for an input that is
linear between samples (first-order hold)::

    eta[k+1] = e^(lambda h) eta[k] + h phi0(lambda h) w[k] + h phi2(lambda h) w[k+1]

with ``w = V^-1 B u``, ``phi1(z) = (e^z - 1)/z``, ``phi2(z) = (e^z - 1 - z)/z^2`` and
``phi0 = phi1 - phi2``. Each mode is one first-order recursion, run over a whole block of
samples at once by ``scipy.signal.lfilter``: vectorised over samples, exact for linear
systems, stable for any step. Only one mode of each complex-conjugate pair is computed
(the input is real, so the partner is its conjugate).

The world advances only when asked (``advance``) - by the DAQ simulator while it acquires,
in sample time; it never sleeps.
"""

from __future__ import annotations

import threading
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from ssid.frf import FRFData, receptance, selection_matrix

from .components import (
    AMP_FAULT_OVER_CURRENT,
    AMP_FAULT_OVER_TEMPERATURE,
    AMP_FAULT_OVER_TRAVEL,
    AmplifierModel,
    AntiAliasFilter,
    GeneratorModel,
    SensorSpec,
    ShakerSpec,
    StandSpec,
)
from .effects import Effect, apply_effects, instability_reason, invalid_parameter
from .world_errors import EffectError, UnstableError, WorldError

__all__ = ["EffectError", "World", "WorldBlock", "WorldError"]


@dataclass
class WorldBlock:
    """One block of samples from :meth:`World.advance`.

    Attributes
    ----------
    first_index : int
        Sample index of the first sample (the world's clock, ticks of 1/fs).
    volts : (n_sensors, n) float
        Transducer output voltages (noise included, clipped at each sensor's range).
    overload : (n_sensors,) bool
        True where a transducer clipped somewhere in the block.
    physical : (n_sensors, n) float
        The measured quantities at the sample instants in SI units, noise-free and before
        the front end's anti-alias filter (for tests).
    """

    first_index: int
    volts: np.ndarray
    overload: np.ndarray
    physical: np.ndarray


def _on_stand(M: np.ndarray, C: np.ndarray, K: np.ndarray, dofs: list[str],
              stand: StandSpec | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K of a structure plus the stand's masses under its reaction DOFs (none: as it is)."""
    n = M.shape[0]
    reactions = list(stand.reactions) if stand else []
    nr = len(reactions)
    Mc = np.zeros((n + nr, n + nr))
    Cc = np.zeros_like(Mc)
    Kc = np.zeros_like(Mc)
    Mc[:n, :n], Cc[:n, :n], Kc[:n, :n] = M, C, K
    if nr:
        Mc[n:, n:] = stand.stand_mass_kg * np.eye(nr)
        T = np.hstack([selection_matrix(dofs, reactions).T, -np.eye(nr)])
        Kc += stand.stand_k_n_per_m * T.T @ T
        Cc += stand.stand_c_n_s_per_m * T.T @ T
        Kc[n:, n:] += stand.ground_k_n_per_m * np.eye(nr)
    return Mc, Cc, Kc


def _phi12(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``phi1 = (e^z - 1)/z`` and ``phi2 = (e^z - 1 - z)/z^2``, with series near zero."""
    z = np.asarray(z, dtype=complex)
    small = np.abs(z) < 1e-3
    zs = np.where(small, 1.0, z)  # avoid 0/0 in the branch not taken
    em1 = np.expm1(zs)
    phi1 = np.where(small, 1 + z / 2 + z**2 / 6 + z**3 / 24, em1 / zs)
    phi2 = np.where(small, 0.5 + z / 6 + z**2 / 24 + z**3 / 120, (em1 - zs) / zs**2)
    return phi1, phi2


class World:
    """Generator -> amplifier -> shaker -> structure -> sensors, advancing in sample time.

    Parameters
    ----------
    M, C, K : (n, n)
        The structure (e.g. ``ssid.models.example_system()`` or the payload simulator).
    dofs : list of str
        Labels of its DOFs.
    shakers : sequence of ShakerSpec
        Shaker ``j`` is fed by amplifier ``j``, whose input is generator
        ``shakers[j].generator`` output ``shakers[j].channel``.
    sensors : sequence of SensorSpec
        Sensor ``i`` is wired to DAQ input ``i``.
    stand : StandSpec, optional
        Flexible test stand with load paths at its reaction DOFs.
    effects : sequence of hidden effects
        Applied to the structure before anything is attached (see ``sim_devices.effects``).
    sample_rate_hz : float
        Initial sample rate (the DAQ simulator sets its own on start).
    noise : bool
        Sensor noise on or off.
    seed : int
        Seed of every random stream (sensor noise, generator noise).
    oversample : int
        Internal steps per output sample (default 1). The drive is linear between internal
        steps, so a sine sampled at the output rate has images near ``fs - f`` that alias
        back onto ``f``; a structure with modes up to a few kHz (the payload simulator)
        needs a finer internal step for sub-percent FRFs at ``fs = 4096``.
    antialias_passband : float or None
        With ``oversample >= 2``, the sensors' voltages pass the DAQ front end's anti-alias
        filter (:class:`~sim_devices.components.AntiAliasFilter`), flat up to this fraction
        of the sample rate (default 0.45, a delta-sigma converter's). None, or one step per
        sample, samples the sensors as they are (what lies above Nyquist folds back).
    """

    def __init__(
        self,
        M: np.ndarray,
        C: np.ndarray | None,
        K: np.ndarray,
        dofs: Sequence[str],
        *,
        shakers: Sequence[ShakerSpec],
        sensors: Sequence[SensorSpec] = (),
        stand: StandSpec | None = None,
        effects: Sequence[Effect] = (),
        sample_rate_hz: float = 5120.0,
        noise: bool = True,
        seed: int = 0,
        oversample: int = 1,
        antialias_passband: float | None = 0.45,
    ) -> None:
        self.lock = threading.RLock()
        self.nominal_dofs = list(dofs)
        if len(set(self.nominal_dofs)) != len(self.nominal_dofs):
            raise WorldError("DOF labels must be unique")
        effects = list(effects)
        for i, eff in enumerate(effects):
            if (bad := invalid_parameter(eff)) is not None:
                raise EffectError(i, eff, *bad)
        self.M_s, self.C_s, self.K_s, self.dofs = apply_effects(M, C, K, list(dofs), list(effects))
        self.shakers = list(shakers)
        if not self.shakers:
            raise WorldError("the world needs at least one shaker")
        for sh in self.shakers:
            self._dof_index(sh.dof, "shaker")
            if sh.channel not in (1, 2):
                raise WorldError(f"shaker at {sh.dof}: generator channel must be 1 or 2")
        self.stand = stand
        self.sensors = list(sensors)
        self.noise = bool(noise)
        n_gen = max(sh.generator for sh in self.shakers) + 1
        self.generators = [GeneratorModel(seed=seed * 7919 + g + 1) for g in range(n_gen)]
        self.amplifiers = [AmplifierModel() for _ in self.shakers]
        self._rng = np.random.default_rng(seed)
        self.oversample = max(1, int(oversample))
        self.antialias_passband = antialias_passband
        self._antialias: AntiAliasFilter | None = None
        try:
            self._assemble()
            self._modalise()
        except UnstableError:
            if not effects:
                raise
            # "Unstable (check M, C, K signs)" does not say which of the setup's effects to mend.
            raise self._unstable_effect(M, C, K, list(dofs), effects) from None
        self.sample_rate_hz = 0.0
        self.set_sample_rate(sample_rate_hz)
        self.reset_state()

    # ------------------------------------------------------------------ assembly
    def _dof_index(self, label: str, what: str) -> int:
        try:
            return self.dofs.index(label)
        except ValueError:
            raise WorldError(f"{what} at unknown DOF {label!r}") from None

    def _structure_with_stand(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M, C, K of structure (with effects) plus stand masses, as in frf_on_test_stand."""
        return _on_stand(self.M_s, self.C_s, self.K_s, self.dofs, self.stand)

    def _unstable_effect(self, M, C, K, dofs: list[str], effects: list[Effect]) -> EffectError:
        """The error naming the first effect with which (and the ones before it) the world is
        unstable, when the world with all of them is: each shorter list is built in turn."""
        for k in range(1, len(effects)):
            try:
                World(M, C, K, dofs, shakers=self.shakers, stand=self.stand, effects=effects[:k], noise=False)
            except EffectError as exc:  # unstable already: it names the effect
                return exc
            except WorldError:  # another fault of a part-built structure: not this question's
                continue
        i = len(effects) - 1
        Ms, Cs, Ks, dofs_i = apply_effects(M, C, K, dofs, effects)
        param, problem = instability_reason(effects[i], *_on_stand(Ms, Cs, Ks, dofs_i, self.stand))
        return EffectError(i, effects[i], param, problem + (" (with the effects before it)" if i else ""))

    def coupled_model(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
        """M, C, K of structure (with its effects) plus stand, and DOF labels.

        The stand mass under reaction DOF ``d`` is labelled ``"stand@<d>"``. This is the model
        an analyst would write for the structure as mounted in the lab.
        """
        Mc, Cc, Kc = self._structure_with_stand()
        reactions = list(self.stand.reactions) if self.stand else []
        return Mc, Cc, Kc, list(self.dofs) + [f"stand@{r}" for r in reactions]

    def fingerprint(self) -> int:
        """A 32-bit number that tells simulated structures apart: of the mounted structure's
        M, C, K (effects and stand included) to 9 digits, its DOFs, the shakers, and each
        sensor's quantity, place and sensitivity (not its name, range or noise, which a
        resume may change). The simulated DAQ front end reports it as its serial number, so
        a run is not resumed on a lab that simulates another structure (as on hardware,
        where another front end has another serial)."""
        Mc, Cc, Kc, dofs = self.coupled_model()
        # Rounded: the same structure assembled in another process must give the same number,
        # whatever the last bits of its sums.
        parts = [np.round(a / (np.max(np.abs(a)) or 1.0) * 1e9).astype(np.int64).tobytes() for a in (Mc, Cc, Kc)]
        parts.append(repr((dofs, self.shakers, [(s.quantity, s.location, f"{s.sensitivity_v_per_unit:.9g}")
                                                for s in self.sensors])).encode())
        return zlib.crc32(b"".join(parts))

    def _assemble(self) -> None:
        """State-space A, B and the output matrix of sensors and shaker monitors."""
        Mc, Cc, Kc = self._structure_with_stand()
        n = self.M_s.shape[0]
        nsr = Mc.shape[0]
        ns = len(self.shakers)
        nq = nsr + ns
        Mq = np.zeros((nq, nq))
        Cq = np.zeros_like(Mq)
        Kq = np.zeros_like(Mq)
        Mq[:nsr, :nsr], Cq[:nsr, :nsr], Kq[:nsr, :nsr] = Mc, Cc, Kc
        Bbl = np.zeros((nq, ns))
        for j, sh in enumerate(self.shakers):
            a, d = nsr + j, self._dof_index(sh.dof, "shaker")
            Mq[a, a] = sh.armature_mass_kg
            Kq[a, a] += sh.suspension_k_n_per_m
            Cq[a, a] += sh.suspension_c_n_s_per_m
            for A, v in ((Kq, sh.stinger_k_n_per_m), (Cq, sh.stinger_c_n_s_per_m)):
                A[a, a] += v
                A[d, d] += v
                A[a, d] -= v
                A[d, a] -= v
            Bbl[a, j] = sh.bl_n_per_a
        try:
            Minv = np.linalg.inv(Mq)
        except np.linalg.LinAlgError:
            raise UnstableError("mass matrix is singular") from None
        L = np.array([sh.coil_l_h for sh in self.shakers])
        R = np.array([sh.coil_r_ohm for sh in self.shakers])
        nz = 2 * nq + ns
        A = np.zeros((nz, nz))
        A[:nq, nq : 2 * nq] = np.eye(nq)
        A[nq : 2 * nq, :nq] = -Minv @ Kq
        A[nq : 2 * nq, nq : 2 * nq] = -Minv @ Cq
        A[nq : 2 * nq, 2 * nq :] = Minv @ Bbl
        A[2 * nq :, nq : 2 * nq] = -(Bbl / L[None, :]).T
        A[2 * nq :, 2 * nq :] = -np.diag(R / L)
        B = np.zeros((nz, ns))
        B[2 * nq :, :] = np.diag(1.0 / L)
        self._A, self._B, self._nq, self._n_struct = A, B, nq, n

        def x_row(q: int) -> np.ndarray:
            r = np.zeros(nz)
            r[q] = 1.0
            return r

        def v_row(q: int) -> np.ndarray:
            r = np.zeros(nz)
            r[nq + q] = 1.0
            return r

        rows = []
        for s in self.sensors:
            if s.quantity == "acceleration":
                rows.append(A[nq + self._dof_index(str(s.location), f"sensor {s.name!r}")])
            elif s.quantity in ("force", "current"):
                j = int(s.location)
                if not 0 <= j < ns:
                    raise WorldError(f"sensor {s.name!r}: no shaker {j}")
                rows.append(self._gauge_row(j, x_row, v_row) if s.quantity == "force" else x_row(2 * nq + j))
            else:  # reaction
                if not self.stand or s.location not in self.stand.reactions:
                    raise WorldError(f"sensor {s.name!r}: {s.location!r} is not a reaction DOF of the stand")
                r = list(self.stand.reactions).index(s.location)
                d, t = self._dof_index(str(s.location), "reaction"), n + r
                st = self.stand
                rows.append(-st.stand_k_n_per_m * (x_row(d) - x_row(t)) - st.stand_c_n_s_per_m * (v_row(d) - v_row(t)))
        # Shaker monitors after the sensors: stinger force, coil current, armature travel.
        for j in range(ns):
            rows.append(self._gauge_row(j, x_row, v_row))
        for j in range(ns):
            rows.append(x_row(2 * nq + j))
        for j in range(ns):
            rows.append(x_row(nsr + j))
        self._Cout = np.array(rows).reshape(len(rows), nz)

    def _gauge_row(self, j, x_row, v_row) -> np.ndarray:
        """Force gauge of shaker j: stinger force pushing on the structure."""
        sh = self.shakers[j]
        a = self._nq - len(self.shakers) + j
        d = self._dof_index(sh.dof, "shaker")
        return sh.stinger_k_n_per_m * (x_row(a) - x_row(d)) + sh.stinger_c_n_s_per_m * (v_row(a) - v_row(d))

    def _modalise(self) -> None:
        lam, V = np.linalg.eig(self._A)
        cond = np.linalg.cond(V)
        if not np.isfinite(cond) or cond > 1e10:
            raise WorldError(
                "the state matrix is (nearly) defective - typically a rigid-body motion with no "
                "path to ground; add a boundary spring (GroundedSpring) or a test stand"
            )
        if np.any(lam.real > 1e-9 * np.abs(lam).max()):
            raise UnstableError("the assembled system is unstable (check M, C, K signs)")
        scale = np.abs(lam).max()
        upper = lam.imag > 1e-12 * scale
        real = np.abs(lam.imag) <= 1e-12 * scale
        keep = np.flatnonzero(upper | real)
        weight = np.where(upper[keep], 2.0, 1.0)  # conjugate partner folded in as 2 Re(...)
        Vinv = np.linalg.inv(V)
        self._lam = lam[keep]
        beta = Vinv[keep] @ self._B  # (n_modes, ns)
        cmod = (self._Cout @ V[:, keep]) * weight[None, :]
        # Real and imaginary parts kept apart: the per-block products then run as real
        # matrix products, which stay fast when the BLAS threads compete for busy cores
        # (small complex products were seen to take milliseconds there). Re(Cmod @ eta) is
        # one product, [Cmod_r, -Cmod_i] @ [eta_r; eta_i], on contiguous rows (the strided
        # eta.real, eta.imag took five times longer).
        self._beta_r, self._beta_i = np.ascontiguousarray(beta.real), np.ascontiguousarray(beta.imag)
        self._Cmod_ri = np.hstack([cmod.real, -cmod.imag])

    # ------------------------------------------------------------------ time stepping
    def set_sample_rate(self, fs_hz: float) -> None:
        """Rediscretise for a new sample rate; the state carries over."""
        if not fs_hz > 0:
            raise WorldError("sample rate must be > 0")
        with self.lock:
            if fs_hz == self.sample_rate_hz:
                return
            h = 1.0 / (fs_hz * self.oversample)
            z = self._lam * h
            phi1, phi2 = _phi12(z)
            self._E = np.exp(z)
            self._g1 = h * phi2
            self._g0 = h * (phi1 - phi2)
            self.sample_rate_hz = float(fs_hz)
            if self.antialias_passband is not None and self.oversample > 1 and self.sensors:
                self._antialias = AntiAliasFilter(fs_hz, self.oversample, self.antialias_passband,
                                                  len(self.sensors))

    def reset_state(self) -> None:
        """Everything at rest, world clock at zero."""
        with self.lock:
            self._eta = np.zeros(self._lam.size, dtype=complex)
            self._u_prev = np.zeros(len(self.shakers))
            self.sample_index = 0
            if self._antialias is not None:
                self._antialias.reset()

    @property
    def time_s(self) -> float:
        return self.sample_index / self.sample_rate_hz

    def _drive(self, n: int) -> np.ndarray:
        """Amplifier output voltages (ns, n) for the next n samples."""
        fs = self.sample_rate_hz * self.oversample
        cache: dict[tuple[int, int], np.ndarray] = {}
        u = np.empty((len(self.shakers), n))
        for j, sh in enumerate(self.shakers):
            key = (sh.generator, sh.channel)
            if key not in cache:
                cache[key] = self.generators[sh.generator].next_samples(sh.channel, n, fs)
            u[j] = self.amplifiers[j].output(cache[key])
        return u

    def advance(self, n: int) -> WorldBlock:
        """Advance ``n`` samples; the sensor voltages at those instants."""
        if n <= 0:
            raise ValueError("n must be > 0")
        with self.lock:
            first = self.sample_index + 1
            ov = self.oversample
            u = self._drive(n * ov)
            uu = np.hstack([self._u_prev[:, None], u])
            w = (self._beta_r @ uu) + 1j * (self._beta_i @ uu)  # (n_modes, n+1), u is real
            eta = np.empty((self._lam.size, n * ov), dtype=complex)
            for m in range(self._lam.size):
                E, g0, g1 = self._E[m], self._g0[m], self._g1[m]
                zi = [g0 * w[m, 0] + E * self._eta[m]]
                eta[m], _ = lfilter([g1, g0], [1.0, -E], w[m, 1:], zi=zi)
            self._eta = eta[:, -1].copy()
            self._u_prev = u[:, -1].copy()
            ns, nsen = len(self.shakers), len(self.sensors)
            eta_ri = np.vstack([eta.real, eta.imag])
            seen = None
            if self._antialias is not None:  # the front end sees every world step
                seen = self._antialias.process(self._Cmod_ri[:nsen] @ eta_ri)
            if ov > 1:
                eta_ri = np.ascontiguousarray(eta_ri[:, ov - 1 :: ov])  # at the output sample instants
            y = self._Cmod_ri @ eta_ri  # Re(Cmod @ eta)
            self.sample_index += n
            self._update_shakers(y[nsen + ns : nsen + 2 * ns], y[nsen + 2 * ns :], n)
            phys = y[:nsen]
            sens = np.array([s.sensitivity_v_per_unit for s in self.sensors])[:, None]
            volts = sens * (phys if seen is None else seen)
            if self.noise:
                noise = np.array([s.noise_volt_rms for s in self.sensors])[:, None]
                volts = volts + noise * self._rng.standard_normal(volts.shape)
            rng_v = np.array([s.range_volt for s in self.sensors])[:, None]
            over = np.any(np.abs(volts) > rng_v, axis=1)
            volts = np.clip(volts, -rng_v, rng_v)
            return WorldBlock(first_index=first, volts=volts, overload=over, physical=phys)

    def _update_shakers(self, current: np.ndarray, travel: np.ndarray, n: int) -> None:
        """Amplifier readings and protection trips (hardware-fast: at block granularity)."""
        dt = n / self.sample_rate_hz
        for j, (sh, amp) in enumerate(zip(self.shakers, self.amplifiers)):
            with amp.lock:
                i_rms = float(np.sqrt(np.mean(current[j] ** 2)))
                amp.current_rms_a = i_rms
                amp.travel_peak_m = float(np.max(np.abs(travel[j])))
                # Coil temperature: exact first-order response to the block's mean power.
                tau = sh.thermal_capacity_j_per_k * sh.thermal_resistance_k_per_w
                t_inf = amp.ambient_c + sh.thermal_resistance_k_per_w * sh.coil_r_ohm * i_rms**2
                amp.temperature_c = t_inf + (amp.temperature_c - t_inf) * np.exp(-dt / tau)
                if amp.temperature_c > sh.temperature_limit_c:
                    amp.trip(AMP_FAULT_OVER_TEMPERATURE)
                elif amp.travel_peak_m > sh.travel_limit_m:
                    amp.trip(AMP_FAULT_OVER_TRAVEL)
                elif i_rms > amp.current_limit_a:
                    amp.trip(AMP_FAULT_OVER_CURRENT)

    # ------------------------------------------------------------------ reference FRFs
    def frf(
        self,
        freq_hz: np.ndarray,
        outputs: Sequence[str] | None = None,
        inputs: Sequence[str] | None = None,
    ) -> FRFData:
        """The true accelerances of the structure as built (hidden effects, stand; no shakers).

        This is what force gauges and accelerometers measure: acceleration at ``outputs``
        per unit force into the structure at ``inputs`` (default: the shaker DOFs). With a
        stand, ``H_reaction`` holds the load-cell forces on the structure per unit input.
        """
        outputs = list(outputs) if outputs is not None else list(self.nominal_dofs)
        inputs = list(inputs) if inputs is not None else [sh.dof for sh in self.shakers]
        Mc, Cc, Kc = self._structure_with_stand()
        n, nc = self.M_s.shape[0], Mc.shape[0]
        freq_hz = np.asarray(freq_hz, dtype=float)
        w = 2 * np.pi * freq_hz
        D = np.vstack([selection_matrix(self.dofs, inputs), np.zeros((nc - n, len(inputs)))])
        X = receptance(Mc, Cc, Kc, w, D)
        S = selection_matrix(self.dofs, outputs).T
        H = -(w**2)[:, None, None] * np.einsum("oi,kij->koj", S, X[:, :n])
        frf = FRFData(freq_hz=freq_hz, H=H, outputs=outputs, inputs=inputs)
        if self.stand:
            reactions = list(self.stand.reactions)
            T = np.hstack([selection_matrix(self.dofs, reactions).T, -np.eye(len(reactions))])
            rel = np.einsum("rq,kqj->krj", T, X)
            st = self.stand
            frf.H_reaction = -(st.stand_k_n_per_m + 1j * w[:, None, None] * st.stand_c_n_s_per_m) * rel
            frf.reactions = reactions
        return frf
