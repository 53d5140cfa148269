"""Component models of the simulated lab: generator outputs, amplifiers, shakers, stand, sensors.

These hold the *state* of each piece of hardware that the physics world needs: what the
signal generator puts out, what the power amplifier does with it (gain, enable, protection
trips), the electrodynamic shaker's parameters, the test stand, and each sensor's wiring.
The instrument simulators (SCPI, Modbus, CAN) change this state; :class:`~sim_devices.world.World`
reads it while it advances in sample time. All changes go through the world's lock.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import butter, fftconvolve, firwin, kaiserord, resample, sosfilt

__all__ = [
    "AMP_FAULT_COMMS_WATCHDOG",
    "AMP_FAULT_INTERLOCK",
    "AMP_FAULT_NONE",
    "AMP_FAULT_OVER_CURRENT",
    "AMP_FAULT_OVER_TEMPERATURE",
    "AMP_FAULT_OVER_TRAVEL",
    "AmplifierModel",
    "AntiAliasFilter",
    "GeneratorChannel",
    "GeneratorModel",
    "SensorSpec",
    "ShakerSpec",
    "StandSpec",
]

# Fault codes of the amplifier (also the Modbus FAULT_CODE register, see docs/drivers.md).
AMP_FAULT_NONE = 0
AMP_FAULT_INTERLOCK = 1
AMP_FAULT_OVER_TEMPERATURE = 2
AMP_FAULT_OVER_TRAVEL = 3
AMP_FAULT_OVER_CURRENT = 4
AMP_FAULT_COMMS_WATCHDOG = 5


@dataclass(frozen=True)
class ShakerSpec:
    """An electrodynamic shaker attached through a stinger and force gauge at a structure DOF.

    The armature (mass ``armature_mass_kg``) sits on a suspension to the (grounded) shaker
    body and is pushed by the coil force ``Bl * i``; the coil obeys
    ``L di/dt = u - R i - Bl v_armature`` (back-EMF), so with a voltage-mode amplifier the
    force drops at structural resonances as on a real shaker. The stinger (``stinger_k``,
    ``stinger_c``) carries the force into the structure; the force gauge at the structure
    end measures exactly that force.

    ``generator``/``channel`` say which generator output drives this shaker's amplifier.
    """

    dof: str
    generator: int = 0
    channel: int = 1
    armature_mass_kg: float = 0.2
    suspension_k_n_per_m: float = 2.0e4
    suspension_c_n_s_per_m: float = 5.0
    coil_r_ohm: float = 1.0
    coil_l_h: float = 2.0e-4
    bl_n_per_a: float = 10.0
    stinger_k_n_per_m: float = 2.0e7
    stinger_c_n_s_per_m: float = 20.0
    travel_limit_m: float = 5.0e-3
    # Coil thermal model: first order, T' = (R i^2 - (T - T_amb)/R_th) / C_th.
    thermal_capacity_j_per_k: float = 50.0
    thermal_resistance_k_per_w: float = 2.0
    temperature_limit_c: float = 120.0


@dataclass(frozen=True)
class StandSpec:
    """A flexible test stand under the structure (as :func:`ssid.models.frf_on_test_stand`).

    Each reaction DOF is tied by a spring-damper (the load cell's load path) to its own stand
    mass on a spring to ground. A load cell at a reaction DOF measures the force the stand
    exerts on the structure, positive along the DOF (contract sign).
    """

    reactions: tuple[str, ...]
    stand_mass_kg: float = 20.0
    stand_k_n_per_m: float = 2.0e6
    stand_c_n_s_per_m: float = 40.0
    ground_k_n_per_m: float = 5.0e6


@dataclass(frozen=True)
class SensorSpec:
    """A transducer wired to one DAQ input.

    Parameters
    ----------
    name : str
        Channel name (free text, e.g. ``"acc 4+Z"``).
    quantity : {"acceleration", "force", "reaction", "current"}
        What it measures: acceleration at DOF ``location`` (m/s^2), the force gauge of shaker
        number ``location`` (N), the load cell at reaction DOF ``location`` (N), or the coil
        current of shaker ``location`` (A, a current monitor).
    location : str or int
        DOF label, or shaker index for ``force`` and ``current``.
    sensitivity_v_per_unit : float
        True sensitivity of the transducer, V per SI unit (10 mV/(m/s^2) is 0.01).
    range_volt : float
        Transducer output swing; beyond it the output clips (overload).
    noise_volt_rms : float
        White noise floor at the transducer output.
    """

    name: str
    quantity: str
    location: str | int
    sensitivity_v_per_unit: float
    range_volt: float = 5.0
    noise_volt_rms: float = 2.0e-6

    def __post_init__(self) -> None:
        if self.quantity not in ("acceleration", "force", "reaction", "current"):
            raise ValueError(f"sensor {self.name!r}: unknown quantity {self.quantity!r}")
        if not self.sensitivity_v_per_unit > 0:
            raise ValueError(f"sensor {self.name!r}: sensitivity must be > 0")


@dataclass
class GeneratorChannel:
    """State of one output of the signal generator (33500B-like)."""

    function: str = "SIN"  # SIN | NOIS | ARB
    freq_hz: float = 1000.0
    vpp: float = 0.1
    offset_volt: float = 0.0
    output_on: bool = False
    arb: np.ndarray = field(default_factory=lambda: np.zeros(8))
    arb_srate_hz: float = 5120.0
    # Running state: phase of the sine (rad), position in the arbitrary waveform (samples).
    phase_rad: float = 0.0
    arb_pos: float = 0.0
    # The waveform's band-limited resampling for one playback ratio (see _arb_at), cached.
    arb_table: tuple = ()
    # Noise bandwidth (FUNC:NOIS:BAND); the 33500B's widest is its default.
    noise_bw_hz: float = 20e6
    # The noise filter for one (bandwidth, rate): (key, sos, state, gain), see _band_limited_noise.
    noise_filter: tuple = ()


class GeneratorModel:
    """Voltage at the outputs of one two-channel signal generator, sample by sample.

    The world asks for the voltage at ``n`` successive sample instants; sine phase and
    waveform position carry over between calls, so a frequency change is phase-continuous
    (as on the 33500B). NOIS is Gaussian with ``sigma = Vpp / 6`` (peaks of about +-3 sigma).
    """

    def __init__(self, seed: int = 0, n_channels: int = 2) -> None:
        self.channels = [GeneratorChannel() for _ in range(n_channels)]
        self._rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """``*RST``: defaults, outputs off."""
        self.channels = [GeneratorChannel() for _ in self.channels]

    def next_samples(self, ch: int, n: int, fs_hz: float) -> np.ndarray:
        """Output voltage of channel ``ch`` (1-based) at the next ``n`` sample instants."""
        c = self.channels[ch - 1]
        j = np.arange(1, n + 1, dtype=float)
        if c.function == "SIN":
            dphi = 2.0 * np.pi * c.freq_hz / fs_hz
            wave = np.sin(c.phase_rad + dphi * j)
            c.phase_rad = float((c.phase_rad + dphi * n) % (2.0 * np.pi))
        elif c.function == "NOIS":
            wave = self._rng.standard_normal(n) / 3.0  # Vpp/2 * N(0,1)/3: sigma = Vpp/6
            if c.noise_bw_hz < 0.45 * fs_hz:  # wider: white at the world's rate is as good
                wave = _band_limited_noise(c, wave, fs_hz)
        elif c.function == "ARB":
            step = c.arb_srate_hz / fs_hz
            wave = _arb_at(c, c.arb_pos + step * j, step)
            c.arb_pos = float((c.arb_pos + step * n) % c.arb.size)
        else:  # pragma: no cover - the SCPI layer only lets the three functions through
            raise ValueError(c.function)
        if not c.output_on:
            return np.zeros(n)
        return c.offset_volt + 0.5 * c.vpp * wave


def _band_limited_noise(c: GeneratorChannel, white: np.ndarray, fs_hz: float) -> np.ndarray:
    """``white`` (at ``fs_hz``) limited to the channel's noise bandwidth, same rms.

    The 33500B's noise is flat up to its set bandwidth; an 8th-order Butterworth low-pass at
    that bandwidth stands in for it (scipy), its state carried across calls so that the
    noise is one continuous record. Scaled by its rms gain, sqrt(noise-equivalent bandwidth
    / (fs / 2)) with NEB = f_c (pi / 2n) / sin(pi / 2n) (within 0.4 % up to 0.45 fs), so
    sigma stays Vpp / 6. A bandwidth below 1e-4 fs is simulated at 1e-4 fs.
    """
    key = (c.noise_bw_hz, fs_hz)
    if not (c.noise_filter and c.noise_filter[0] == key):
        order = 8
        f_c = max(c.noise_bw_hz, 1e-4 * fs_hz)
        sos = butter(order, f_c, fs=fs_hz, output="sos")
        q = np.pi / (2 * order)
        gain = float(np.sqrt(f_c * q / np.sin(q) / (0.5 * fs_hz)))
        c.noise_filter = (key, sos, np.zeros((sos.shape[0], 2)), gain)
    _, sos, zi, gain = c.noise_filter
    out, zf = sosfilt(sos, white, zi=zi)
    c.noise_filter = (key, sos, zf, gain)
    return out / gain


def _arb_at(c: GeneratorChannel, pos: np.ndarray, step: float) -> np.ndarray:
    """The arbitrary waveform of ``c`` at fractional sample positions ``pos``, played as the
    33500B plays arbs with its default (normal) filter: point by point through a DAC and a
    reconstruction filter, i.e. band-limited below half the arb sample rate.

    A zero-order hold instead puts images of every line f at ``srate - f`` (a quarter of
    the line's amplitude at f = srate / 5); a DAQ sampling at the arb rate folds the
    structure's response to them back onto f, which biased simulated periodic-random FRFs
    by up to 20 % near 800 Hz at 4096 S/s. The waveform is periodic, so its band-limited
    form is its Fourier series: resampled by FFT (scipy) when the world steps through it
    at an integer number of points per sample (the random runs: arb rate = DAQ rate), summed
    directly otherwise (n N / 2 terms for n instants of an N-point arb).
    """
    arb = c.arb
    up = round(1.0 / step) if step > 0 else 0
    on_grid = up >= 1 and abs(up * step - 1.0) < 1e-9 and abs(pos[0] * up - round(pos[0] * up)) < 1e-6
    if on_grid:
        if not (c.arb_table and c.arb_table[0] is arb and c.arb_table[1] == up):
            c.arb_table = (arb, up, resample(arb, arb.size * up) if up > 1 else arb)
        table = c.arb_table[2]
        return table[np.rint(pos * up).astype(np.int64) % table.size]
    N = arb.size
    X = np.fft.rfft(arb) / N
    w = np.full(X.size, 2.0)
    w[0] = 1.0
    if N % 2 == 0:
        w[-1] = 1.0  # the Nyquist line once, as cos (its sine part is zero at the points)
    k = np.arange(X.size)
    out = np.empty(pos.size)
    rows = max(1, 2**21 // X.size)  # phase matrices of at most 2M entries (32 MB)
    for a in range(0, pos.size, rows):
        ph = np.exp(2j * np.pi * np.outer(pos[a:a + rows], k) / N)
        out[a:a + rows] = (ph * (w * X)).real.sum(axis=1)
    return out


class AmplifierModel:
    """A voltage-mode shaker power amplifier with hardware protection.

    Output voltage ``u = clip(gain * v_in, +-max_output_volt)`` while enabled. It trips
    (disables itself and latches a fault code) when the interlock opens, the coil
    overheats, the armature over-travels or the current exceeds its limit; a tripped
    amplifier can only be enabled again after the cause is gone and the fault is reset.
    """

    def __init__(self, max_output_volt: float = 20.0, current_limit_a: float = 10.0) -> None:
        self.lock = threading.RLock()
        self.max_output_volt = max_output_volt
        self.current_limit_a = current_limit_a
        self.enabled = False
        self.gain_v_per_v = 1.0
        self.interlock_closed = True
        self.fault_code = AMP_FAULT_NONE
        self.temperature_c = 25.0
        self.ambient_c = 25.0
        self.current_rms_a = 0.0
        self.travel_peak_m = 0.0

    def request_enable(self) -> int:
        """Try to enable; returns the fault code that refuses it (0: enabled)."""
        with self.lock:
            if not self.interlock_closed:
                return AMP_FAULT_INTERLOCK
            if self.fault_code != AMP_FAULT_NONE:
                return self.fault_code
            self.enabled = True
            return AMP_FAULT_NONE

    def disable(self) -> None:
        with self.lock:
            self.enabled = False

    def trip(self, code: int) -> None:
        """Protection trip: output off at once, fault latched."""
        with self.lock:
            self.enabled = False
            if self.fault_code == AMP_FAULT_NONE:
                self.fault_code = code

    def reset_fault(self) -> bool:
        """Clear the latched fault if its cause is gone; True when cleared."""
        with self.lock:
            if not self.interlock_closed:
                return False
            if self.fault_code == AMP_FAULT_OVER_TEMPERATURE and self.temperature_c > self.ambient_c + 60:
                return False
            self.fault_code = AMP_FAULT_NONE
            return True

    def set_interlock(self, closed: bool) -> None:
        """Open or close the interlock loop (door, E-stop); opening trips the amplifier."""
        with self.lock:
            self.interlock_closed = bool(closed)
            if not closed:
                self.trip(AMP_FAULT_INTERLOCK)

    def output(self, v_in: np.ndarray) -> np.ndarray:
        """Amplifier output voltage for input samples ``v_in``."""
        with self.lock:
            if not self.enabled:
                return np.zeros_like(v_in)
            return np.clip(self.gain_v_per_v * v_in, -self.max_output_volt, self.max_output_volt)


class AntiAliasFilter:
    """The DAQ front end's anti-alias filter, run at the world's internal step.

    A delta-sigma converter samples far above its output rate and decimates through a
    linear-phase digital low-pass; this is that filter for ``oversample`` world steps per
    output sample: a Kaiser-window FIR (scipy), flat to 1e-5 up to ``passband * fs`` and
    100 dB down from ``(1 - passband) * fs``, above which content would fold back into the
    passband. Its delay is a whole number of world steps, ``(n_taps - 1) / 2`` (the same on
    every channel, so FRFs, ratios of channels, do not see it). Content between the passband
    and ``(1 - passband) * fs`` folds onto the band above the passband, as on a real front
    end, which is why a test's band must end at the passband (``[daq] passband_fraction``).

    Parameters
    ----------
    fs_hz : float
        Output sample rate.
    oversample : int
        World steps per output sample, at least 2 (with one step the world holds nothing
        above Nyquist to remove).
    passband : float
        Passband edge as a fraction of ``fs_hz``, in (0, 0.5).
    n_channels : int
        Channels filtered together; each keeps its own history across calls.
    """

    def __init__(self, fs_hz: float, oversample: int, passband: float, n_channels: int) -> None:
        if oversample < 2 or not 0 < passband < 0.5:
            raise ValueError("the anti-alias filter needs oversample >= 2 and 0 < passband < 0.5")
        fw = fs_hz * oversample
        n_taps, beta = kaiserord(100.0, (1 - 2 * passband) * fs_hz / (0.5 * fw))
        n_taps |= 1  # odd: linear phase with a delay of whole world steps
        self.taps = firwin(n_taps, 0.5 * fs_hz, window=("kaiser", beta), fs=fw)
        self.oversample = int(oversample)
        self.delay_steps = (n_taps - 1) // 2
        self._hist = np.zeros((n_channels, n_taps - 1))

    def reset(self) -> None:
        self._hist[:] = 0.0

    def process(self, x: np.ndarray) -> np.ndarray:
        """Filter and decimate ``x: (n_channels, n * oversample)`` (world steps) to
        ``(n_channels, n)`` output samples; the history carries over to the next call."""
        buf = np.concatenate([self._hist, x], axis=1)
        self._hist = buf[:, x.shape[1]:].copy()
        # By FFT, all world steps: 2.4 times faster here than a polyphase decimator (upfirdn)
        # computing only the outputs. 'valid' output i is the filter's output at x[:, i];
        # the samples sit at the last world step of each sample, as the unfiltered world's do.
        ov = self.oversample
        return fftconvolve(buf, self.taps[None, :], mode="valid", axes=1)[:, ov - 1 :: ov]
