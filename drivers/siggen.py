"""Device layer: a two-channel SCPI arbitrary waveform generator (33500B-like command set).

Safety rules built in: amplitudes are ramped while an output is on (never stepped),
settings are range-checked before they are sent and the error queue is read after each,
and :meth:`SignalGenerator.safe_state` (also on every exit of the context manager) turns
every output off, ramping down first when the link allows it.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence

import numpy as np

from .errors import ConnectionLost, InstrumentError, ProtocolError, RangeError
from .interrupts import interrupts_held
from .scpi import ScpiProtocol
from .serial_line import SerialLine

__all__ = ["GeneratorLimits", "SignalGenerator"]

log = logging.getLogger(__name__)


class GeneratorLimits:
    """Ranges of the instrument into a high-impedance load (the amplifier input)."""

    freq_min_hz = 1e-6
    freq_max_hz = 20e6
    vpp_min = 2e-3
    vpp_max = 20.0
    peak_max_volt = 10.0
    srate_min_hz = 1.0
    srate_max_hz = 250e6
    arb_min_points = 8
    arb_max_points = 1_000_000
    noise_bw_min_hz = 1e-3
    noise_bw_max_hz = 20e6


FUNCTIONS = ("SIN", "NOIS", "ARB")


class SignalGenerator:
    """Driver of one signal generator.

    Parameters
    ----------
    url : str
        Serial port or pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/3``, ``socket://127.0.0.1:5025``).
    name : str
        Name used in messages.
    timeout_s : float
        Reply timeout of every query.
    max_vpp : float
        Safety limit on the amplitude (Vpp) for this set-up, at most the instrument's 20 Vpp.
    ramp_time_s, ramp_step_s : float
        Amplitude ramps take ``ramp_time_s`` in steps of ``ramp_step_s`` (per full scale of
        the change; small changes take proportionally fewer steps, at least one).
    channels : int
        Number of outputs (2).
    """

    def __init__(
        self,
        url: str,
        *,
        name: str = "siggen",
        baudrate: int = 115200,
        timeout_s: float = 1.0,
        max_vpp: float = GeneratorLimits.vpp_max,
        ramp_time_s: float = 0.5,
        ramp_step_s: float = 0.05,
        channels: int = 2,
    ) -> None:
        if not 0 < max_vpp <= GeneratorLimits.vpp_max:
            raise RangeError(f"{name}: max_vpp must be in (0, {GeneratorLimits.vpp_max:g}] V")
        self.name = name
        self.max_vpp = float(max_vpp)
        self.ramp_time_s = float(ramp_time_s)
        self.ramp_step_s = float(ramp_step_s)
        self.channels = tuple(range(1, channels + 1))
        try:
            self.line = SerialLine(url, baudrate=baudrate, timeout_s=timeout_s)
        except ConnectionLost as exc:  # the port alone does not say which instrument is missing
            raise ConnectionLost(f"{name}: {exc}") from exc
        self.scpi = ScpiProtocol(self.line, name)
        self._vpp = {ch: GeneratorLimits.vpp_min for ch in self.channels}
        # The offset as set (or read at connect): an amplitude is range-checked with it, since
        # the instrument refuses |offset| + Vpp/2 > 10 V only once a ramp has begun.
        self._offset = {ch: 0.0 for ch in self.channels}
        self._on = {ch: False for ch in self.channels}
        try:
            self.idn = self.scpi.query("*IDN?")
            if self.idn.count(",") < 3:
                raise ProtocolError(f"{name}: unexpected *IDN? reply {self.idn[:60]!r}")
            self.scpi.write("*CLS")
            for ch in self.channels:
                self._vpp[ch] = self._query_number(f"SOUR{ch}:VOLT?")
                self._offset[ch] = self._query_number(f"SOUR{ch}:VOLT:OFFS?")
                self._on[ch] = self.scpi.query(f"OUTP{ch}?").strip() in ("1", "ON")
        except BaseException:
            self.line.close()
            raise

    # ------------------------------------------------------------------ settings
    def _ch(self, ch: int) -> int:
        if ch not in self.channels:
            raise RangeError(f"{self.name}: no channel {ch} (have {self.channels})")
        return ch

    def reset(self) -> None:
        """``*RST``: instrument defaults, all outputs off."""
        self.scpi.write("*RST", check=False)
        self.scpi.opc()
        self.scpi.check_errors("*RST")
        for ch in self.channels:
            self._on[ch] = False
            self._vpp[ch] = self._query_number(f"SOUR{ch}:VOLT?")
            self._offset[ch] = self._query_number(f"SOUR{ch}:VOLT:OFFS?")

    def _query_number(self, command: str) -> float:
        """The reply to ``command`` as a finite number.

        Raises
        ------
        ProtocolError
            The reply is not one (an ASCII reply the link passes as text, but garbage).
        """
        reply = self.scpi.query(command)
        try:
            value = float(reply)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise ProtocolError(f"{self.name}: unexpected {command} reply {reply[:60]!r} (not a number)")
        return value

    def set_function(self, ch: int, function: str) -> None:
        """``SIN``, ``NOIS`` or ``ARB`` (the arbitrary waveform must be uploaded first)."""
        f = function.upper()
        if f not in FUNCTIONS:
            raise RangeError(f"{self.name}: function must be one of {FUNCTIONS}, not {function!r}")
        self.scpi.write(f"SOUR{self._ch(ch)}:FUNC {f}")

    def set_frequency(self, ch: int, freq_hz: float) -> None:
        lim = GeneratorLimits
        if not (math.isfinite(freq_hz) and lim.freq_min_hz <= freq_hz <= lim.freq_max_hz):
            raise RangeError(f"{self.name}: frequency {freq_hz!r} Hz outside [{lim.freq_min_hz:g}, {lim.freq_max_hz:g}]")
        self.scpi.write(f"SOUR{self._ch(ch)}:FREQ {freq_hz:.12g}")

    def set_noise_bandwidth(self, ch: int, bandwidth_hz: float) -> None:
        """Bandwidth of the ``NOIS`` function (flat up to it): keep the drive's power in the
        analysis band rather than spend it, and the amplifier's headroom, above."""
        lim = GeneratorLimits
        if not (math.isfinite(bandwidth_hz) and lim.noise_bw_min_hz <= bandwidth_hz <= lim.noise_bw_max_hz):
            raise RangeError(f"{self.name}: noise bandwidth {bandwidth_hz!r} Hz outside "
                             f"[{lim.noise_bw_min_hz:g}, {lim.noise_bw_max_hz:g}]")
        self.scpi.write(f"SOUR{self._ch(ch)}:FUNC:NOIS:BAND {bandwidth_hz:.12g}")

    def set_offset(self, ch: int, volt: float) -> None:
        self._check_peak(self._vpp[self._ch(ch)], volt)
        self.scpi.write(f"SOUR{ch}:VOLT:OFFS {volt:.12g}")
        self._offset[ch] = float(volt)

    def _check_vpp(self, vpp: float) -> None:
        if not (math.isfinite(vpp) and GeneratorLimits.vpp_min <= vpp <= self.max_vpp):
            raise RangeError(
                f"{self.name}: amplitude {vpp!r} Vpp outside [{GeneratorLimits.vpp_min:g}, {self.max_vpp:g}] "
                "(instrument range and this set-up's safety limit)"
            )

    def _check_amplitude(self, ch: int, vpp: float) -> None:
        """``vpp`` within the instrument's and this set-up's range, and its peak with the
        channel's offset within the output's."""
        self._check_vpp(vpp)
        self._check_peak(vpp, self._offset[ch])

    def _check_peak(self, vpp: float, offset: float) -> None:
        if not math.isfinite(offset) or abs(offset) + vpp / 2 > GeneratorLimits.peak_max_volt:
            raise RangeError(f"{self.name}: |offset| + Vpp/2 must stay within {GeneratorLimits.peak_max_volt:g} V")

    def set_amplitude(self, ch: int, vpp: float, ramp_time_s: float | None = None) -> None:
        """Set the amplitude (Vpp); ramped in steps while the output is on."""
        ch = self._ch(ch)
        self._check_amplitude(ch, vpp)
        self._ramp(ch, vpp, self.ramp_time_s if ramp_time_s is None else ramp_time_s)

    def _ramp(self, ch: int, target: float, ramp_time_s: float) -> None:
        start = self._vpp[ch]
        if self._on[ch] and ramp_time_s > 0 and target != start:
            frac = abs(target - start) / self.max_vpp
            n = max(1, math.ceil(frac * ramp_time_s / self.ramp_step_s))
            steps = np.linspace(start, target, n + 1)[1:]
        else:
            steps = np.array([target])
        for i, v in enumerate(steps):
            if i:
                time.sleep(self.ramp_step_s)
            self.scpi.write(f"SOUR{ch}:VOLT {v:.9g}")
            self._vpp[ch] = float(v)

    def upload_arb(self, ch: int, samples: Sequence[float] | np.ndarray, sample_rate_hz: float, name: str = "SSID") -> float:
        """Upload a waveform for periodic or burst random and select it on channel ``ch``.

        The waveform is scaled to peak 1 (the instrument's -1..+1 data range); the output
        then spans ``offset +- Vpp/2``. Burst random: append zeros to the burst. Returns the
        scale factor applied, so that the caller knows volts = Vpp/2 * scale * samples.
        """
        x = np.asarray(samples, dtype=float).ravel()
        lim = GeneratorLimits
        if not lim.arb_min_points <= x.size <= lim.arb_max_points:
            raise RangeError(f"{self.name}: waveform needs {lim.arb_min_points}..{lim.arb_max_points} points, got {x.size}")
        if not np.all(np.isfinite(x)) or not np.any(x):
            raise RangeError(f"{self.name}: waveform must be finite and not all zero")
        if not lim.srate_min_hz <= sample_rate_hz <= lim.srate_max_hz:
            raise RangeError(f"{self.name}: sample rate {sample_rate_hz!r} outside [{lim.srate_min_hz:g}, {lim.srate_max_hz:g}] Hz")
        ch = self._ch(ch)
        scale = 1.0 / np.max(np.abs(x))
        values = ",".join(f"{v:.7g}" for v in x * scale)
        self.scpi.write(f"SOUR{ch}:DATA:ARB {name},{values}")
        self.scpi.write(f"SOUR{ch}:FUNC:ARB {name}")
        self.scpi.write(f"SOUR{ch}:FUNC:ARB:SRAT {sample_rate_hz:.12g}")
        self.scpi.write(f"SOUR{ch}:FUNC ARB")
        return float(scale)

    # ------------------------------------------------------------------ output
    def output_on(self, ch: int, vpp: float | None = None, ramp_time_s: float | None = None) -> None:
        """Switch the output on at the lowest amplitude, then ramp up to ``vpp`` (if given)."""
        ch = self._ch(ch)
        if vpp is not None:
            self._check_amplitude(ch, vpp)
        if not self._on[ch]:
            self.scpi.write(f"SOUR{ch}:VOLT {GeneratorLimits.vpp_min:.9g}")
            self._vpp[ch] = GeneratorLimits.vpp_min
            self.scpi.write(f"OUTP{ch} ON")
            self._on[ch] = True
        if vpp is not None:
            self._ramp(ch, vpp, self.ramp_time_s if ramp_time_s is None else ramp_time_s)

    def output_off(self, ch: int, ramp_time_s: float | None = None) -> None:
        """Ramp down to the lowest amplitude, then switch the output off."""
        ch = self._ch(ch)
        try:
            if self._on[ch]:
                self._ramp(ch, GeneratorLimits.vpp_min, self.ramp_time_s if ramp_time_s is None else ramp_time_s)
        finally:
            # Whatever happened during the ramp, the output must end up off.
            self.scpi.write(f"OUTP{ch} OFF")
            self._on[ch] = False

    def is_on(self, ch: int) -> bool:
        """Output state as last set by this driver."""
        return self._on[self._ch(ch)]

    def recover(self) -> None:
        """Resynchronise after a timeout or garbled reply (flush, ``*CLS``, ``*OPC?``)."""
        self.scpi.resync()

    def safe_state(self, ramp_time_s: float = 0.1) -> None:
        """All outputs off (quick ramp down when the link works); never hangs.

        Raises the first error only if some output could not be confirmed off.
        """
        failures: list[str] = []
        for ch in self.channels:
            try:
                self.output_off(ch, ramp_time_s=ramp_time_s)
                continue
            except InstrumentError as exc:
                log.warning("%s: ramp-down of channel %d failed: %s", self.name, ch, exc)
            # Second chance without the ramp, after resynchronising the dialogue.
            try:
                self.scpi.resync(attempts=1)
                self.scpi.write(f"OUTP{ch} OFF")
                self._on[ch] = False
            except InstrumentError as exc:
                failures.append(f"channel {ch}: {exc}")
        if failures:
            raise InstrumentError(f"{self.name}: could not confirm outputs off: " + "; ".join(failures))

    def close(self) -> None:
        """Safe state, then release the port (the port is released even if safe_state fails).
        A Ctrl-C meanwhile is raised when the port is released: inside the safe state it could
        cut the ``OUTP OFF`` that ends it, and the output stayed on."""
        with interrupts_held:
            try:
                if self.line.is_open:
                    self.safe_state()
            finally:
                self.line.close()

    def release(self) -> None:
        """Release the port without another safe state: for a caller that has just brought
        this generator to its safe state, or tried to and could not confirm it (an instrument
        that stopped answering would cost each further attempt its time-outs)."""
        self.line.close()

    def __enter__(self) -> SignalGenerator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
