"""Simulated two-channel signal generator speaking SCPI on a pseudo-terminal or TCP socket.

The command set follows the Keysight 33500B series closely enough that the same driver can
talk to either (see ``docs/drivers.md``): ``*IDN?``, ``*RST``, ``*CLS``, ``*OPC?``,
``SYSTem:ERRor?``, ``[SOURce[n]:]FUNCtion SIN|NOISe|ARB``, ``FREQuency``, ``VOLTage`` (Vpp),
``VOLTage:OFFSet``, ``FUNCtion:ARBitrary <name>``, ``FUNCtion:ARBitrary:SRATe``,
``DATA:ARBitrary <name>,<v>,...`` (ASCII values in -1..1), ``DATA:VOLatile:CLEar`` and
``OUTPut[n] ON|OFF``, with short/long mnemonics, ``;``-separated commands and queries.
Errors go to an error queue read with ``SYSTem:ERRor?``.

Transports: ``"pty"`` (Linux pseudo-terminal; the driver opens :attr:`url`, a ``/dev/pts/N``
path, as a serial port) or ``"tcp"`` (a socket on 127.0.0.1 with an ephemeral port; the
driver opens ``socket://127.0.0.1:PORT`` through pyserial).

Faults for tests (:meth:`inject`): ``"garbage"`` (a reply replaced by junk),
``"silent"`` (a query gets no reply), ``"partial"`` (a reply cut short, no terminator).
"""

from __future__ import annotations

import os
import re
import select
import socket
import threading
import tty

import numpy as np

from .world import World

__all__ = ["SimSignalGenerator"]

# Limits of the simulated instrument (high-Z load); the driver has the same numbers.
FREQ_MIN_HZ, FREQ_MAX_HZ = 1e-6, 20e6
VPP_MIN, VPP_MAX = 2e-3, 20.0
PEAK_MAX_VOLT = 10.0
SRATE_MIN_HZ, SRATE_MAX_HZ = 1.0, 250e6
NOISE_BW_MIN_HZ, NOISE_BW_MAX_HZ = 1e-3, 20e6
ARB_MIN_POINTS, ARB_MAX_POINTS = 8, 1_000_000
ERROR_QUEUE_LEN = 20

_ERRORS = {
    -100: "Command error",
    -104: "Data type error",
    -109: "Missing parameter",
    -113: "Undefined header",
    -221: "Settings conflict",
    -222: "Data out of range",
    -224: "Illegal parameter value",
    -350: "Queue overflow",
}


def _mnemonic(long_form: str) -> re.Pattern:
    """Regex for a SCPI mnemonic: its short form (the upper-case part) or long form, any case."""
    short = "".join(ch for ch in long_form if ch.isupper())
    return re.compile(rf"^(?:{short}|{long_form.upper()})$", re.IGNORECASE)


_M = {name: _mnemonic(name) for name in (
    "FUNCtion", "FREQuency", "VOLTage", "OFFSet", "ARBitrary", "SRATe", "DATA", "VOLatile",
    "CLEar", "SYSTem", "ERRor", "NOISe", "BANDwidth",
)}
_SOURCE = re.compile(r"^(?:SOUR|SOURCE)([12]?)$", re.IGNORECASE)
_OUTPUT = re.compile(r"^(?:OUTP|OUTPUT)([12]?)$", re.IGNORECASE)


class _ScpiError(Exception):
    def __init__(self, code: int, detail: str = "") -> None:
        super().__init__(code, detail)
        self.code = code
        self.detail = detail


class SimSignalGenerator:
    """A simulated SCPI signal generator bound to generator ``index`` of ``world``.

    Use as a context manager, or call :meth:`start` and :meth:`stop`.
    """

    def __init__(self, world: World, index: int = 0, transport: str = "pty", seed: int = 0,
                 serial: str | None = None) -> None:
        if transport not in ("pty", "tcp"):
            raise ValueError("transport must be 'pty' or 'tcp'")
        self.world = world
        self.index = index
        self.serial = serial or f"SN{index:05d}"  # in *IDN?; tests set another for a replaced unit
        self.model = world.generators[index]
        self.transport = transport
        self.url = ""
        self.errors: list[tuple[int, str]] = []
        self.arbs: dict[str, np.ndarray] = {}
        self.arb_name = ["", ""]
        self._faults: dict[str, int] = {"garbage": 0, "silent": 0, "partial": 0}
        self._rng = np.random.default_rng(seed)
        self._thread: threading.Thread | None = None
        self._stop_r, self._stop_w = -1, -1
        self._fds: list[int] = []
        self._sock: socket.socket | None = None
        self._conn: socket.socket | None = None
        self.log: list[str] = []  # every command received, for tests and debugging

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimSignalGenerator:
        self._stop_r, self._stop_w = os.pipe()
        if self.transport == "pty":
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no line discipline: bytes pass through as on a UART
            self._master, self._slave = master, slave
            self._fds = [master, slave]
            self.url = os.ttyname(slave)
        else:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind(("127.0.0.1", 0))  # loopback only
            self._sock.listen(1)
            self.url = f"socket://127.0.0.1:{self._sock.getsockname()[1]}"
        self._thread = threading.Thread(target=self._serve, name=f"sim-siggen-{self.index}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._thread is None:
            return
        os.write(self._stop_w, b"x")
        self._thread.join(timeout=5.0)
        self._thread = None
        for fd in self._fds + [self._stop_r, self._stop_w]:
            try:
                os.close(fd)
            except OSError:
                pass
        for s in (self._conn, self._sock):
            if s is not None:
                s.close()
        self._fds, self._conn, self._sock = [], None, None

    def __enter__(self) -> SimSignalGenerator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def inject(self, kind: str, count: int = 1) -> None:
        """Make the next ``count`` replies faulty: ``garbage``, ``silent`` or ``partial``."""
        if kind not in self._faults:
            raise ValueError(f"unknown serial fault {kind!r}")
        self._faults[kind] = count

    # ------------------------------------------------------------------ I/O loop
    def _serve(self) -> None:
        buf = b""
        while True:
            rd = [self._stop_r]
            if self.transport == "pty":
                rd.append(self._master)
            else:
                rd.append(self._conn.fileno() if self._conn else self._sock.fileno())
            ready, _, _ = select.select(rd, [], [], 0.5)
            if self._stop_r in ready:
                return
            if not ready:
                continue
            if self.transport == "tcp" and self._conn is None:
                self._conn, _ = self._sock.accept()
                buf = b""
                continue
            try:
                data = os.read(self._master, 65536) if self.transport == "pty" else self._conn.recv(65536)
            except OSError:
                data = b""
            if not data:
                if self.transport == "tcp":  # client went away: wait for the next one
                    self._conn.close()
                    self._conn = None
                continue
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = self._handle_line(line.decode("ascii", "replace").strip())
                if reply is not None:
                    self._send_reply(reply)

    def _send_reply(self, reply: str) -> None:
        data = (reply + "\n").encode()
        if self._faults["silent"]:
            self._faults["silent"] -= 1
            return
        if self._faults["garbage"]:
            self._faults["garbage"] -= 1
            data = bytes(self._rng.integers(0x80, 0xFF, 12, dtype=np.uint8)) + b"\n"
        elif self._faults["partial"]:
            self._faults["partial"] -= 1
            data = data[: max(1, len(data) // 2)].rstrip(b"\n")
        try:
            if self.transport == "pty":
                os.write(self._master, data)
            elif self._conn is not None:
                self._conn.sendall(data)
        except OSError:
            pass

    # ------------------------------------------------------------------ SCPI parser
    def _push_error(self, code: int, detail: str = "") -> None:
        if len(self.errors) >= ERROR_QUEUE_LEN:
            self.errors[-1] = (-350, _ERRORS[-350])
            return
        msg = _ERRORS.get(code, "Error")
        self.errors.append((code, f"{msg}; {detail}" if detail else msg))

    def _handle_line(self, line: str) -> str | None:
        """Execute one line (commands separated by ';'); the joined query replies."""
        if not line:
            return None
        self.log.append(line)
        replies = []
        for cmd in (c.strip() for c in line.split(";")):
            if not cmd:
                continue
            try:
                r = self._execute(cmd)
            except _ScpiError as exc:
                self._push_error(exc.code, exc.detail)
                r = None
            if r is not None:
                replies.append(r)
        return ";".join(replies) if replies else None

    def _execute(self, cmd: str) -> str | None:
        header, _, arg = cmd.partition(" ")
        arg = arg.strip()
        query = header.endswith("?")
        header = header.rstrip("?")
        up = header.upper()
        if up.startswith("*"):
            return self._common(up, query)
        parts = [p for p in header.split(":") if p]
        ch = 1
        if parts and (m := _SOURCE.match(parts[0])):
            ch = int(m.group(1) or 1)
            parts = parts[1:]
        elif parts and (m := _OUTPUT.match(parts[0])):
            return self._output(int(m.group(1) or 1), arg, query, parts[1:])
        names = [self._name(p) for p in parts]
        with self.world.lock:
            c = self.model.channels[ch - 1]
            if names == ["SYSTem", "ERRor"] and query:
                code, msg = self.errors.pop(0) if self.errors else (0, "No error")
                return f'{code:+d},"{msg}"'
            if names == ["FUNCtion"]:
                if query:
                    return c.function
                return self._set_function(ch, arg)
            if names == ["FREQuency"]:
                if query:
                    return f"{c.freq_hz:.12g}"
                c.freq_hz = self._number(arg, FREQ_MIN_HZ, FREQ_MAX_HZ)
                return None
            if names == ["VOLTage"]:
                if query:
                    return f"{c.vpp:.12g}"
                vpp = self._number(arg, VPP_MIN, VPP_MAX)
                self._check_peak(vpp, c.offset_volt)
                c.vpp = vpp
                return None
            if names == ["VOLTage", "OFFSet"]:
                if query:
                    return f"{c.offset_volt:.12g}"
                off = self._number(arg, -PEAK_MAX_VOLT, PEAK_MAX_VOLT)
                self._check_peak(c.vpp, off)
                c.offset_volt = off
                return None
            if names == ["FUNCtion", "ARBitrary"]:
                if query:
                    return f'"{self.arb_name[ch - 1]}"'
                name = arg.strip('"').upper()
                if name not in self.arbs:
                    raise _ScpiError(-224, f"no arbitrary waveform named {name!r}")
                self._select_arb(ch, name)
                return None
            if names == ["FUNCtion", "ARBitrary", "SRATe"]:
                if query:
                    return f"{c.arb_srate_hz:.12g}"
                c.arb_srate_hz = self._number(arg, SRATE_MIN_HZ, SRATE_MAX_HZ)
                return None
            if names == ["FUNCtion", "NOISe", "BANDwidth"]:
                if query:
                    return f"{c.noise_bw_hz:.12g}"
                c.noise_bw_hz = self._number(arg, NOISE_BW_MIN_HZ, NOISE_BW_MAX_HZ)
                return None
            if names == ["DATA", "ARBitrary"] and not query:
                return self._upload(arg)
            if names == ["DATA", "VOLatile", "CLEar"] and not query:
                if any(ch_.function == "ARB" and ch_.output_on for ch_ in self.model.channels):
                    raise _ScpiError(-221, "cannot clear a waveform that is playing")
                self.arbs.clear()
                return None
        raise _ScpiError(-113, cmd)

    def _name(self, token: str) -> str:
        for name, pat in _M.items():
            if pat.match(token):
                return name
        raise _ScpiError(-113, token)

    def _common(self, up: str, query: bool) -> str | None:
        if up == "*IDN" and query:
            return f"ssidlab,SIM-33522,{self.serial},1.0"
        if up == "*OPC" and query:
            return "1"
        if up == "*RST" and not query:
            with self.world.lock:
                self.model.reset()
                self.arb_name = ["", ""]
            return None
        if up == "*CLS" and not query:
            self.errors.clear()
            return None
        raise _ScpiError(-113, up)

    def _output(self, ch: int, arg: str, query: bool, rest: list[str]) -> str | None:
        if rest:
            raise _ScpiError(-113, ":".join(rest))
        with self.world.lock:
            c = self.model.channels[ch - 1]
            if query:
                return "1" if c.output_on else "0"
            a = arg.upper()
            if a in ("ON", "1"):
                c.output_on = True
            elif a in ("OFF", "0"):
                c.output_on = False
            else:
                raise _ScpiError(-224, arg)
        return None

    @staticmethod
    def _number(arg: str, lo: float, hi: float) -> float:
        if not arg:
            raise _ScpiError(-109)
        try:
            v = float(arg)
        except ValueError:
            raise _ScpiError(-104, arg) from None
        if not (np.isfinite(v) and lo <= v <= hi):
            raise _ScpiError(-222, f"{v:g} outside [{lo:g}, {hi:g}]")
        return v

    @staticmethod
    def _check_peak(vpp: float, offset: float) -> None:
        if abs(offset) + vpp / 2 > PEAK_MAX_VOLT + 1e-12:
            raise _ScpiError(-221, f"|offset| + Vpp/2 exceeds {PEAK_MAX_VOLT:g} V")

    def _set_function(self, ch: int, arg: str) -> None:
        a = arg.upper()
        c = self.model.channels[ch - 1]
        if a in ("SIN", "SINUSOID"):
            c.function = "SIN"
        elif a in ("NOIS", "NOISE"):
            c.function = "NOIS"
        elif a in ("ARB", "ARBITRARY"):
            if not self.arb_name[ch - 1]:
                raise _ScpiError(-221, "no arbitrary waveform selected")
            c.function = "ARB"
            c.arb_pos = 0.0
        else:
            raise _ScpiError(-224, arg)

    def _select_arb(self, ch: int, name: str) -> None:
        c = self.model.channels[ch - 1]
        c.arb = self.arbs[name]
        c.arb_pos = 0.0
        self.arb_name[ch - 1] = name

    def _upload(self, arg: str) -> None:
        name, _, values = arg.partition(",")
        name = name.strip().strip('"').upper()
        if not re.fullmatch(r"[A-Z][A-Z0-9_]{0,11}", name):
            raise _ScpiError(-224, f"bad waveform name {name!r}")
        try:
            data = np.array([float(v) for v in values.split(",")], dtype=float)
        except ValueError:
            raise _ScpiError(-104, "waveform values must be numbers") from None
        if not ARB_MIN_POINTS <= data.size <= ARB_MAX_POINTS:
            raise _ScpiError(-222, f"waveform needs {ARB_MIN_POINTS}..{ARB_MAX_POINTS} points")
        if not np.all(np.isfinite(data)) or np.max(np.abs(data)) > 1.0:
            raise _ScpiError(-222, "waveform values must be within -1..+1")
        self.arbs[name] = data
