"""The test setup file (TOML): parsing and validation into :class:`TestSetup`.

Every key is checked before any instrument is touched. A bad file raises
:class:`ssid.errors.InputError` with one line that names the file and the key, e.g.
``setup.toml: [stepped_sine] f_max_hz: must be greater than f_min_hz (20)``.
The keys are documented in ``docs/acquisition.md``.
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ssid.errors import InputError

from .rms_limit import RMS_LIMIT_KEYS, refuse_rms_limits
from .toml_table import TomlTable

__all__ = [
    "AmplifierSpec", "ChannelSpec", "DaqSpec", "GeneratorSpec", "Limits", "RandomSpec",
    "ShakerSetup", "SineSpec", "TestSetup", "load_setup", "parse_setup",
]

QUANTITIES = ("acceleration", "force", "reaction")
COUPLINGS = ("DC", "AC", "IEPE")


@dataclass(frozen=True)
class GeneratorSpec:
    name: str
    url: str
    max_vpp: float = 10.0
    timeout_s: float = 1.0
    ramp_time_s: float = 0.2


@dataclass(frozen=True)
class AmplifierSpec:
    name: str
    host: str
    port: int
    gain_v_per_v: float = 1.0
    device_id: int = 1


@dataclass(frozen=True)
class ShakerSetup:
    dof: str
    generator: str
    channel: int
    amplifier: str
    force_channel: str


@dataclass(frozen=True)
class ChannelSpec:
    name: str
    input: int
    dof: str
    quantity: str
    sensitivity_mv_per_unit: float
    range_volt: float = 10.0
    coupling: str = "DC"


@dataclass(frozen=True)
class DaqSpec:
    interface: str = "virtual"
    channel: str = "ssidlab-daq"
    sample_rate_hz: int = 4096
    nominal_bitrate: int = 1_000_000
    data_bitrate: int = 5_000_000
    #: The front end's alias-free band as a fraction of ``sample_rate_hz`` (its anti-alias
    #: filter's passband edge): about 0.45 for a delta-sigma converter, 1/2.56 for an
    #: analyser with an analog filter. No test band may reach past it.
    passband_fraction: float = 0.45
    #: The -3 dB corner of the front end's AC/IEPE coupling (a first-order high-pass), Hz:
    #: divided out of the AC and IEPE channels' spectra when FRFs are formed (daq.coupling).
    ac_corner_hz: float = 0.5

    @property
    def passband_hz(self) -> float:
        return self.passband_fraction * self.sample_rate_hz


@dataclass(frozen=True)
class SineSpec:
    """Stepped-sine settings (``[stepped_sine]``)."""

    f_min_hz: float
    f_max_hz: float
    n_lines: int = 50
    spacing: str = "log"
    refine: int = 8
    max_change: float = 0.25
    force_n: float = 1.0
    control: str = "force"
    control_target: float = 0.0
    tolerance: float = 0.15
    compression: float = 2.0
    accuracy: float = 1e-3
    min_cycles: float = 8.0
    min_dwell_s: float = 0.05
    max_settle_s: float = 20.0
    max_dwell_s: float = 10.0
    initial_vpp: float = 0.05
    damping_guess: float = 0.01


@dataclass(frozen=True)
class RandomSpec:
    """Random-excitation settings (``[random]``)."""

    kind: str
    f_min_hz: float
    f_max_hz: float
    block_size: int = 2048
    averages: int = 16
    overlap: float = 0.5
    window: str = "hann"
    drive_vpp: float = 1.0
    estimator: str = "H1"
    burst_fraction: float = 0.5
    settle_blocks: int = 2
    seed: int = 0
    accuracy: float = 1e-3
    max_settle_s: float = 20.0


@dataclass(frozen=True)
class Limits:
    max_drive_vpp: float = 10.0
    max_force_n: float = math.inf
    max_accel_m_per_s2: float = math.inf
    max_reaction_n: float = math.inf
    # RMS over daq.rms_limit.RMS_WINDOW_S, random only: the largest sample of Gaussian drive
    # grows with the record, so a peak limit alone trips by chance (docs/acquisition.md).
    max_accel_rms_m_per_s2: float = math.inf
    max_force_rms_n: float = math.inf
    max_reaction_rms_n: float = math.inf


@dataclass
class TestSetup:
    """A validated test setup. ``text`` and ``sha256`` identify the file for resume."""

    source: str
    text: str
    sha256: str
    name: str
    output_file: str
    uff_file: str | None
    raw_time: bool
    daq: DaqSpec
    generators: list[GeneratorSpec]
    amplifiers: list[AmplifierSpec]
    shakers: list[ShakerSetup]
    channels: list[ChannelSpec]
    excitation: str
    sine: SineSpec | None
    random: RandomSpec | None
    limits: Limits
    min_coherence: float
    sim: dict = field(default_factory=dict)

    # Derived views -------------------------------------------------------------------
    @property
    def outputs(self) -> list[str]:
        """DOF labels of the accelerometers (the FRF outputs), in channel order."""
        return [c.dof for c in self.channels if c.quantity == "acceleration"]

    @property
    def inputs(self) -> list[str]:
        return [s.dof for s in self.shakers]

    @property
    def reactions(self) -> list[str]:
        return [c.dof for c in self.channels if c.quantity == "reaction"]

    def drive_limit_vpp(self, shaker: int) -> float:
        """Largest drive of shaker ``shaker`` (index): ``[limits] max_drive_vpp`` or its
        generator's ``max_vpp``, whichever is smaller (the driver refuses more)."""
        gen = next(g for g in self.generators if g.name == self.shakers[shaker].generator)
        return min(self.limits.max_drive_vpp, gen.max_vpp)

    def channel_ranges(self) -> np.ndarray:
        """Each channel's DAQ input range in its own unit (m/s^2 or N): ``range_volt`` over
        the sensitivity, ``(n_ch,)``."""
        return np.array([c.range_volt * 1e3 / c.sensitivity_mv_per_unit for c in self.channels])

    def channel_index(self, name: str) -> int:
        return [c.name for c in self.channels].index(name)

    def roles(self) -> dict[str, list[int]]:
        """Channel indices of the force gauges (shaker order), responses and reactions."""
        return {
            "force": [self.channel_index(s.force_channel) for s in self.shakers],
            "response": [i for i, c in enumerate(self.channels) if c.quantity == "acceleration"],
            "reaction": [i for i, c in enumerate(self.channels) if c.quantity == "reaction"],
        }


def _tables(src: str, doc: dict, key: str) -> list[TomlTable]:
    items = doc.get(key, [])
    if not isinstance(items, list) or not items:
        raise InputError(f"{src}: [[{key}]]: at least one entry is required")
    return [TomlTable(src, f"[[{key}]] #{i + 1}", t) for i, t in enumerate(items)]


def load_setup(path: str | Path) -> TestSetup:
    """Read and validate a setup file."""
    p = Path(path)
    src = str(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{src}: no such file") from None
    except OSError as exc:
        raise InputError(f"{src}: cannot read ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{src}: not UTF-8 text") from None
    if not text.strip():  # TOML takes it, and its first complaint would be a missing [output]
        raise InputError(f"{src}: empty file (a setup file, SETUP.toml, was expected)")
    return parse_setup(text, src)


def parse_setup(text: str, src: str = "setup") -> TestSetup:
    """Validate the TOML ``text`` of a setup file (``src`` names it in messages)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{src}: not valid TOML ({exc})") from None
    known = {"test", "output", "daq", "generators", "amplifiers", "shakers", "channels",
             "excitation", "stepped_sine", "random", "limits", "quality", "sim"}
    extra = sorted(set(doc) - known)
    if extra:
        raise InputError(f"{src}: [{extra[0]}]: unknown table")

    test = TomlTable(src, "[test]", doc.get("test", {}))
    name = test.str("name", "ssidlab test")
    test.str("operator", None)
    test.done()

    out = TomlTable(src, "[output]", doc.get("output", {}))
    output_file = out.str("file", required=True)
    uff_file = out.str("uff", None)
    raw_time = out.bool("raw_time", False)
    out.done()

    from drivers.daq import can_interfaces

    dq = TomlTable(src, "[daq]", doc.get("daq", {}))
    daq = DaqSpec(
        # A misspelt interface is a setup error (exit 2), not a lost link to check (exit 3).
        interface=dq.str("interface", "virtual", choices=can_interfaces()), channel=dq.str("channel", "ssidlab-daq"),
        sample_rate_hz=dq.int("sample_rate_hz", 4096, lo=1, hi=102400),
        nominal_bitrate=dq.int("nominal_bitrate", 1_000_000, lo=10_000, hi=1_000_000),
        data_bitrate=dq.int("data_bitrate", 5_000_000, lo=100_000, hi=8_000_000),
        passband_fraction=dq.num("passband_fraction", 0.45, lo=0.1, hi=0.49),
        ac_corner_hz=dq.num("ac_corner_hz", 0.5, lo=0.0, lo_open=True, hi=100.0),
    )
    dq.done()

    generators = []
    for t in _tables(src, doc, "generators"):
        generators.append(GeneratorSpec(
            name=t.str("name", required=True), url=t.str("url", required=True),
            max_vpp=t.num("max_vpp", 10.0, lo=0.002, hi=20.0),
            timeout_s=t.num("timeout_s", 1.0, lo=0.01, hi=60.0, lo_open=True),
            ramp_time_s=t.num("ramp_time_s", 0.2, lo=0.0, hi=60.0)))
        t.done()
    amplifiers = []
    for t in _tables(src, doc, "amplifiers"):
        amplifiers.append(AmplifierSpec(
            name=t.str("name", required=True), host=t.str("host", "127.0.0.1"),
            port=t.int("port", 502, lo=0, hi=65535),
            # 0 passes no drive: the level control would run the generator to its limit on
            # every line for a force of nothing.
            gain_v_per_v=t.num("gain_v_per_v", 1.0, lo=0.0, lo_open=True, hi=50.0),
            device_id=t.int("device_id", 1, lo=0, hi=247)))
        t.done()
    channels = []
    for t in _tables(src, doc, "channels"):
        q = t.str("quantity", required=True, choices=QUANTITIES)
        channels.append(ChannelSpec(
            name=t.str("name", required=True), input=t.int("input", required=True, lo=0, hi=31),
            dof=t.str("dof", required=True), quantity=q,
            sensitivity_mv_per_unit=t.num("sensitivity_mv_per_unit", required=True, lo=0.0, lo_open=True,
                                          hi=1e6),
            range_volt=t.num("range_volt", 10.0, lo=0.1, hi=10.0),
            coupling=t.str("coupling", "DC", choices=COUPLINGS)))
        t.done()
    shakers = []
    for t in _tables(src, doc, "shakers"):
        shakers.append(ShakerSetup(
            dof=t.str("dof", required=True), generator=t.str("generator", required=True),
            channel=t.int("channel", 1, lo=1, hi=2), amplifier=t.str("amplifier", required=True),
            force_channel=t.str("force_channel", required=True)))
        t.done()
    _check_wiring(src, generators, amplifiers, shakers, channels)

    ex = TomlTable(src, "[excitation]", doc.get("excitation", {}))
    excitation = ex.str("type", required=True, choices=("stepped_sine", "random"))
    ex.done()
    sine = _parse_sine(src, doc, channels, daq) if excitation == "stepped_sine" else None
    rnd = _parse_random(src, doc, daq) if excitation == "random" else None
    if rnd is not None and rnd.estimator == "H2" and len(shakers) > 1:
        raise InputError(f"{src}: [random] estimator: H2 needs a single shaker; use H1 or Hv with several")
    if excitation == "stepped_sine" and "random" in doc:
        raise InputError(f"{src}: [random]: given but [excitation] type is stepped_sine")
    if excitation == "random" and "stepped_sine" in doc:
        raise InputError(f"{src}: [stepped_sine]: given but [excitation] type is random")

    lim = TomlTable(src, "[limits]", doc.get("limits", {}))
    limits = Limits(
        max_drive_vpp=lim.num("max_drive_vpp", 10.0, lo=0.002, hi=20.0),
        max_force_n=lim.num("max_force_n", math.inf, lo=0.0, lo_open=True),
        max_accel_m_per_s2=lim.num("max_accel_m_per_s2", math.inf, lo=0.0, lo_open=True),
        max_reaction_n=lim.num("max_reaction_n", math.inf, lo=0.0, lo_open=True),
        # Zero, negative or NaN would trip at once or never: refused like the peak limits.
        **{k: lim.num(k, math.inf, lo=0.0, lo_open=True) for k in RMS_LIMIT_KEYS})
    lim.done()
    if excitation == "stepped_sine":
        refuse_rms_limits(src, lim.data)
    qual = TomlTable(src, "[quality]", doc.get("quality", {}))
    min_coh = qual.num("min_coherence", 0.9, lo=0.0, hi=1.0)
    qual.done()
    sim = doc.get("sim", {})
    if not isinstance(sim, dict):
        raise InputError(f"{src}: [sim]: must be a table")
    setup = TestSetup(
        source=src, text=text, sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(), name=name,
        output_file=output_file, uff_file=uff_file, raw_time=raw_time, daq=daq,
        generators=generators, amplifiers=amplifiers, shakers=shakers, channels=channels,
        excitation=excitation, sine=sine, random=rnd, limits=limits, min_coherence=min_coh, sim=sim)
    if excitation == "stepped_sine":
        # Both would stop or spoil every run of this setup: a first drive above the limit is
        # cut to it and can overshoot the force limit on the first line; a force target at
        # or above the force limit cannot be held.
        _refuse_drive_above_limit(setup, "[stepped_sine] initial_vpp", sine.initial_vpp)
        if sine.control == "force" and sine.force_n >= limits.max_force_n:
            raise InputError(f"{src}: [stepped_sine] force_n: {sine.force_n:g} N is not below [limits] max_force_n "
                             f"({limits.max_force_n:g} N): the level control could not hold it")
    if excitation == "random":
        # The random level is fixed: one the generator refuses would stop every run of
        # this setup at its start, as an instrument error.
        _refuse_drive_above_limit(setup, "[random] drive_vpp", rnd.drive_vpp)
    return setup


def _refuse_drive_above_limit(setup: TestSetup, key: str, vpp: float) -> None:
    """Refuse a drive level ``vpp`` (the setup's ``key``) above what a shaker may get."""
    for p, sh in enumerate(setup.shakers):
        if vpp > setup.drive_limit_vpp(p):
            raise InputError(
                f"{setup.source}: {key}: {vpp:g} Vpp is more than shaker {sh.dof!r} may get, "
                f"{setup.drive_limit_vpp(p):g} Vpp ([limits] max_drive_vpp, or the max_vpp of generator "
                f"{sh.generator!r})")


def _unique(src: str, table: str, key: str, values: list) -> None:
    seen = set()
    for i, v in enumerate(values):
        if v in seen:
            raise InputError(f"{src}: [[{table}]] #{i + 1} {key}: {v!r} used twice")
        seen.add(v)


def _check_wiring(src, generators, amplifiers, shakers, channels) -> None:
    """Cross-references between tables: names exist, nothing is used twice."""
    _unique(src, "generators", "name", [g.name for g in generators])
    _unique(src, "amplifiers", "name", [a.name for a in amplifiers])
    _unique(src, "channels", "name", [c.name for c in channels])
    _unique(src, "channels", "input", [c.input for c in channels])
    _unique(src, "shakers", "dof", [s.dof for s in shakers])
    _unique(src, "shakers", "amplifier", [s.amplifier for s in shakers])
    _unique(src, "shakers", "generator/channel", [(s.generator, s.channel) for s in shakers])
    _unique(src, "shakers", "force_channel", [s.force_channel for s in shakers])
    by_name = {c.name: c for c in channels}
    for i, s in enumerate(shakers):
        where = f"{src}: [[shakers]] #{i + 1}"
        if s.generator not in {g.name for g in generators}:
            raise InputError(f"{where} generator: no [[generators]] named {s.generator!r}")
        if s.amplifier not in {a.name for a in amplifiers}:
            raise InputError(f"{where} amplifier: no [[amplifiers]] named {s.amplifier!r}")
        c = by_name.get(s.force_channel)
        if c is None or c.quantity != "force":
            raise InputError(f"{where} force_channel: no force channel named {s.force_channel!r}")
        if c.dof != s.dof:
            raise InputError(f"{where} force_channel: {c.name!r} is at {c.dof!r}, the shaker at {s.dof!r}")
    outputs = [c.dof for c in channels if c.quantity == "acceleration"]
    if not outputs:
        raise InputError(f"{src}: [[channels]]: at least one acceleration channel is required")
    _unique(src, "channels", "dof (acceleration)", outputs)
    _unique(src, "channels", "dof (reaction)", [c.dof for c in channels if c.quantity == "reaction"])
    forces = {s.force_channel for s in shakers}
    for i, c in enumerate(channels):
        if c.quantity == "force" and c.name not in forces:
            raise InputError(f"{src}: [[channels]] #{i + 1} name: force channel {c.name!r} belongs to no shaker")
    for i, s in enumerate(shakers):
        if s.dof not in outputs:
            raise InputError(f"{src}: [[shakers]] #{i + 1} dof: no acceleration channel at {s.dof!r} "
                             "(each input must also be an output)")
    for i, c in enumerate(channels):
        if c.quantity == "reaction" and c.dof not in outputs:
            raise InputError(f"{src}: [[channels]] #{i + 1} dof: reaction at {c.dof!r} needs an "
                             "acceleration channel at the same DOF")


def _f_max_in_passband(t: TomlTable, daq: DaqSpec) -> float:
    """``f_max_hz``, refused beyond the DAQ's alias-free band: above it the anti-alias filter
    takes the response away (or, without one, what is read is folded)."""
    f_max = t.num("f_max_hz", required=True, lo=0.0, lo_open=True)
    if f_max > daq.passband_hz * (1 + 1e-12):
        raise t.error("f_max_hz", f"{f_max:g} Hz is beyond the DAQ's alias-free band, {daq.passband_hz:g} Hz "
                      f"([daq] passband_fraction {daq.passband_fraction:g} x sample_rate_hz "
                      f"{daq.sample_rate_hz}): raise sample_rate_hz or lower f_max_hz")
    return f_max


def _parse_sine(src: str, doc: dict, channels: list[ChannelSpec], daq: DaqSpec) -> SineSpec:
    t = TomlTable(src, "[stepped_sine]", doc.get("stepped_sine", {}))
    f_min = t.num("f_min_hz", required=True, lo=0.0, lo_open=True, hi=1e5)
    f_max = _f_max_in_passband(t, daq)
    if f_max <= f_min:
        raise t.error("f_max_hz", f"must be greater than f_min_hz ({f_min:g})")
    control = t.str("control", "force")
    if control != "force":
        match = [c for c in channels if c.name == control]
        if not match or match[0].quantity != "acceleration":
            raise t.error("control", f"must be 'force' or the name of an acceleration channel, got {control!r}")
    spec = SineSpec(
        f_min_hz=f_min, f_max_hz=f_max, n_lines=t.int("n_lines", 50, lo=2, hi=100_000),
        spacing=t.str("spacing", "log", choices=("log", "linear")),
        refine=t.int("refine", 8, lo=1, hi=64),
        max_change=t.num("max_change", 0.25, lo=0.01, hi=2.0),
        force_n=t.num("force_n", 1.0, lo=0.0, lo_open=True, finite=True),
        control=control,
        control_target=t.num("control_target", 0.0, lo=0.0, finite=True),
        tolerance=t.num("tolerance", 0.15, lo=0.001, hi=1.0),
        compression=t.num("compression", 2.0, lo=1.0, hi=100.0, lo_open=True),
        accuracy=t.num("accuracy", 1e-3, lo=1e-7, hi=0.5),
        min_cycles=t.num("min_cycles", 8.0, lo=1.0, hi=1e5),
        min_dwell_s=t.num("min_dwell_s", 0.05, lo=0.0, hi=600.0),
        max_settle_s=t.num("max_settle_s", 20.0, lo=0.0, hi=3600.0, lo_open=True),
        max_dwell_s=t.num("max_dwell_s", 10.0, lo=0.0, hi=3600.0, lo_open=True),
        initial_vpp=t.num("initial_vpp", 0.05, lo=0.002, hi=20.0),
        damping_guess=t.num("damping_guess", 0.01, lo=1e-5, hi=0.5))
    if control != "force" and spec.control_target <= 0:
        raise t.error("control_target", "must be > 0 (m/s^2) when control is an accelerometer")
    if spec.max_dwell_s < spec.min_dwell_s:
        raise t.error("max_dwell_s", f"must be at least min_dwell_s ({spec.min_dwell_s:g} s)")
    t.done()
    return spec


def _parse_random(src: str, doc: dict, daq: DaqSpec) -> RandomSpec:
    t = TomlTable(src, "[random]", doc.get("random", {}))
    f_min = t.num("f_min_hz", required=True, lo=0.0, lo_open=True, hi=1e5)
    f_max = _f_max_in_passband(t, daq)
    if f_max <= f_min:
        raise t.error("f_max_hz", f"must be greater than f_min_hz ({f_min:g})")
    spec = RandomSpec(
        kind=t.str("kind", required=True, choices=("random", "periodic", "burst")),
        f_min_hz=f_min, f_max_hz=f_max,
        block_size=t.int("block_size", 2048, lo=64, hi=262_144),
        averages=t.int("averages", 16, lo=1, hi=100_000),
        overlap=t.num("overlap", 0.5, lo=0.0, hi=0.9),
        window=t.str("window", "hann", choices=("hann", "rect")),
        drive_vpp=t.num("drive_vpp", 1.0, lo=0.002, hi=20.0),
        estimator=t.str("estimator", "H1", choices=("H1", "H2", "Hv")),
        burst_fraction=t.num("burst_fraction", 0.5, lo=0.05, hi=0.95),
        settle_blocks=t.int("settle_blocks", 2, lo=0, hi=100),
        seed=t.int("seed", 0, lo=0),
        accuracy=t.num("accuracy", 1e-3, lo=0.0, hi=0.5),
        max_settle_s=t.num("max_settle_s", 20.0, lo=0.0, hi=3600.0, lo_open=True))
    for key in ("accuracy", "max_settle_s"):
        if key in doc.get("random", {}) and spec.kind == "random":
            raise t.error(key, "applies to kind = \"periodic\" or \"burst\" only (their steady-state check)")
    if spec.f_min_hz < daq.sample_rate_hz / spec.block_size:
        raise t.error("f_min_hz", f"below the frequency resolution {daq.sample_rate_hz / spec.block_size:g} Hz "
                      "(sample_rate_hz / block_size)")
    t.done()
    return spec
