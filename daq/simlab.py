"""Start the simulated lab for a setup (``ssidlab acquire --sim``).

This is the only module of ``daq`` that imports ``sim_devices``. It builds a physics world
that matches the setup - one simulated sensor per DAQ input, one shaker per ``[[shakers]]``
entry on the named generator output, a test stand under the reaction DOFs - starts every
simulated instrument on its real transport (:class:`sim_devices.lab.SimLab`) and returns a
copy of the setup whose addresses point at them. The run logic then talks to the
simulated instruments through the ordinary drivers, exactly as to real ones.

``[sim]`` keys (all optional; ``docs/acquisition.md``):

* ``structure``: ``"payload"`` (the payload simulator's 16 Z DOFs, Guyan-reduced, with modal
  damping ``damping_ratio``) or ``"example"`` (the bundled 14-DOF example);
* ``damping_ratio`` (payload only, default 0.02), ``noise`` (default true), ``seed``;
* ``sensor_noise_volt_rms`` (default 2e-6), ``sensor_range_volt`` (default 5);
* ``generator_transport``: ``"pty"`` or ``"tcp"`` (default ``"tcp"``);
* ``oversample``: internal time steps per sample of the world (default 4: a structure with
  modes near the sample rate needs 4 or more, see :class:`sim_devices.world.World`); with 2
  or more the simulated front end's anti-alias filter (``[daq] passband_fraction``) acts on
  the internal steps, as a real front end's always does; 1 samples the world unfiltered;
* ``sensitivity_error``: a table of channel name = factor, the factor by which that
  transducer's true sensitivity differs from the setup's (a calibration gone wrong, which
  the run's reciprocity check should find);
* ``[sim.stand]``: ``stand_mass_kg``, ``stand_k_n_per_m``, ``stand_c_n_s_per_m``,
  ``ground_k_n_per_m`` of the stand under each reaction DOF;
* ``[[sim.effects]]``: hidden effects, ``type`` one of ``added_mass`` (``dof``,
  ``mass_kg``), ``grounded_spring`` (``dof``, ``stiffness_n_per_m``), ``coupling_spring``
  (``dof_a``, ``dof_b``, ``stiffness_n_per_m``), ``grounded_damper`` (``dof``,
  ``damping_n_s_per_m``), ``attached_oscillator`` (``dof``, ``mass_kg``,
  ``stiffness_n_per_m``, ``damping_n_s_per_m``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drivers.errors import SensorOverload
from ssid.errors import InputError
from ssid.io import Model

from .coupling import AC_COUPLINGS
from .setup import TestSetup
from .toml_table import TomlTable

__all__ = ["EXAMPLE_HIDDEN", "EXAMPLE_SHAKERS", "SimHandle", "WorldRig", "build_world", "example_setup_text",
           "payload_substructure", "start_sim_lab"]

EFFECT_KEYS = {
    "added_mass": ("AddedMass", ["dof", "mass_kg"]),
    "grounded_spring": ("GroundedSpring", ["dof", "stiffness_n_per_m"]),
    "coupling_spring": ("CouplingSpring", ["dof_a", "dof_b", "stiffness_n_per_m"]),
    "grounded_damper": ("GroundedDamper", ["dof", "damping_n_s_per_m"]),
    "attached_oscillator": ("AttachedOscillator", ["dof", "mass_kg", "stiffness_n_per_m", "damping_n_s_per_m"]),
}


def payload_substructure(damping_ratio: float = 0.02) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The payload simulator reduced to its 16 Z DOFs (Guyan), with modal damping.

    This is the nominal model of the ``"payload"`` structure (no hidden effects).
    """
    from ssid.models.payload import Z_DOFS, modal_damping, payload_simulator
    from ssid.tam import guyan_reduce

    p = payload_simulator()
    sub = guyan_reduce(p.M, p.K, p.index(Z_DOFS))
    M, K = (sub.M + sub.M.T) / 2, (sub.K + sub.K.T) / 2
    return M, modal_damping(M, K, damping_ratio), K, list(Z_DOFS)


def build_world(setup: TestSetup):
    """The :class:`sim_devices.world.World` that matches ``setup`` (see the module docstring)."""
    from sim_devices import effects as eff_mod
    from sim_devices.components import SensorSpec, ShakerSpec, StandSpec
    from sim_devices.world import EffectError, World, WorldError
    from ssid.models import example_system

    src = setup.source
    sim = dict(setup.sim)
    stand_raw = sim.pop("stand", {})
    effects_raw = sim.pop("effects", [])
    miscalibrated = _sensitivity_errors(setup, sim.pop("sensitivity_error", {}))
    t = TomlTable(src, "[sim]", sim)
    structure = t.str("structure", "example", choices=("payload", "example"))
    zeta = t.num("damping_ratio", 0.02, lo=0.0, hi=0.5)
    noise = t.bool("noise", True)
    seed = t.int("seed", 0, lo=0)
    # finite=True: an inf in these tables otherwise reached the world's matrices and came
    # back as "Array must not contain infs", or as a defective state matrix, naming no key.
    noise_v = t.num("sensor_noise_volt_rms", 2e-6, lo=0.0, finite=True)
    range_v = t.num("sensor_range_volt", 5.0, lo=0.01, lo_open=True, finite=True)
    t.str("generator_transport", "tcp", choices=("pty", "tcp"))
    oversample = t.int("oversample", 4, lo=1, hi=64)
    t.done()
    st = TomlTable(src, "[sim.stand]", stand_raw)
    stand_kw = {k: st.num(k, getattr(StandSpec, k), lo=0.0, finite=True)
                for k in ("stand_mass_kg", "stand_k_n_per_m", "stand_c_n_s_per_m", "ground_k_n_per_m")}
    st.done()
    if not isinstance(effects_raw, list):
        raise InputError(f"{src}: [[sim.effects]]: must be an array of tables")
    effects = []
    for i, raw in enumerate(effects_raw):
        e = TomlTable(src, f"[[sim.effects]] #{i + 1}", raw)
        kind = e.str("type", required=True, choices=tuple(EFFECT_KEYS))
        cls_name, keys = EFFECT_KEYS[kind]
        args = [e.str(k, required=True) if k.startswith("dof") else e.num(k, required=True, finite=True)
                for k in keys]
        e.done()
        effects.append(getattr(eff_mod, cls_name)(*args))

    if structure == "payload":
        M, C, K, dofs = payload_substructure(zeta)
    else:
        M, C, K, dofs = example_system(14, seed=1)
    gen_index = {g.name: i for i, g in enumerate(setup.generators)}
    used = {gen_index[s.generator] for s in setup.shakers}
    if used != set(range(len(setup.generators))):
        unused = [g.name for i, g in enumerate(setup.generators) if i not in used]
        raise InputError(f"{src}: [[generators]]: {unused[0]!r} drives no shaker (the simulated lab "
                         "builds one generator per shaker group)")
    shakers = [ShakerSpec(s.dof, generator=gen_index[s.generator], channel=s.channel) for s in setup.shakers]
    force_of = {s.force_channel: j for j, s in enumerate(setup.shakers)}
    by_input = {c.input: c for c in setup.channels}
    sensors = []
    for k in range(max(by_input) + 1):
        c = by_input.get(k)
        if c is None:  # an unused input still needs something wired to it
            sensors.append(SensorSpec(f"unused {k}", "acceleration", dofs[0], 0.01, range_v, noise_v))
        else:
            # The transducer's own sensitivity; the acquisition goes by the setup's.
            v_per_unit = c.sensitivity_mv_per_unit / 1e3 * miscalibrated.get(c.name, 1.0)
            where = force_of[c.name] if c.quantity == "force" else c.dof
            sensors.append(SensorSpec(c.name, c.quantity, where, v_per_unit, range_v, noise_v))
    reactions = tuple(setup.reactions)
    stand = StandSpec(reactions, **stand_kw) if reactions else None
    try:
        return World(M, C, K, dofs, shakers=shakers, sensors=sensors, stand=stand, effects=effects,
                     sample_rate_hz=setup.daq.sample_rate_hz, noise=noise, seed=seed, oversample=oversample,
                     antialias_passband=setup.daq.passband_fraction)
    except EffectError as exc:
        # The entry to mend, by its place in the file, its type, DOF and value.
        raise InputError(f"{src}: [[sim.effects]] #{exc.index + 1} {exc.entry}") from None
    except (WorldError, ValueError) as exc:
        # Without a [sim] table every key is its default (the 14-DOF example structure): a
        # setup for the payload then fails on a DOF, which would not say why.
        hint = "" if setup.sim else (
            " (the setup has no [sim] table, so the simulated structure is the default 'example', "
            "DOFs 1+Z to 14+Z; the payload's needs structure = \"payload\")")
        raise InputError(f"{src}: [sim]: {exc}{hint}") from None


def _sensitivity_errors(setup: TestSetup, raw) -> dict[str, float]:
    """``[sim] sensitivity_error``: channel name -> the factor by which that transducer's true
    sensitivity differs from the setup's (a calibration sheet that is off, for tests of what
    the acquisition's checks find)."""
    where = f"{setup.source}: [sim] sensitivity_error"
    if not isinstance(raw, dict):
        raise InputError(f"{where}: must be a table of channel name = factor")
    names = {c.name for c in setup.channels}
    for name, factor in raw.items():
        if name not in names:
            raise InputError(f"{where}: no channel named {name!r}")
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not 0.1 <= factor <= 10:
            raise InputError(f"{where}: {name!r}: a factor between 0.1 and 10, got {factor!r}")
    return {name: float(factor) for name, factor in raw.items()}


@dataclasses.dataclass
class SimHandle:
    """A running simulated lab; :meth:`stop` ends it."""

    lab: object
    world: object

    def stop(self) -> None:
        self.lab.stop()


def start_sim_lab(setup: TestSetup, world=None) -> tuple[SimHandle, TestSetup]:
    """Start the simulated lab for ``setup`` (on ``world``, :func:`build_world`'s for it, if
    built already); the handle and the setup pointed at it."""
    from sim_devices.lab import SimLab

    world = build_world(setup) if world is None else world
    transport = setup.sim.get("generator_transport", "tcp")
    # The simulated front end is the one the setup describes: its anti-alias passband (in the
    # world) and its AC/IEPE coupling corner.
    lab = SimLab(world, generator_transport=transport, ac_corner_hz=setup.daq.ac_corner_hz).start()
    try:
        ep = lab.endpoints()
        gens = [dataclasses.replace(g, url=ep["generators"][i]) for i, g in enumerate(setup.generators)]
        amp_of = {s.amplifier: j for j, s in enumerate(setup.shakers)}
        amps = []
        for a in setup.amplifiers:
            if a.name not in amp_of:
                raise InputError(f"{setup.source}: [[amplifiers]]: {a.name!r} feeds no shaker")
            e = ep["amplifiers"][amp_of[a.name]]
            amps.append(dataclasses.replace(a, host=e["host"], port=e["port"], device_id=e["device_id"]))
        daq = dataclasses.replace(setup.daq, interface="virtual", channel=ep["daq"]["can_channel"])
        new = dataclasses.replace(setup, generators=gens, amplifiers=amps, daq=daq)
    except BaseException:
        lab.stop()
        raise
    return SimHandle(lab, world), new


class WorldRig:
    """A :class:`daq.rig.Rig` on a world directly, without transports (benchmarks, fast tests).

    Same channels, shakers and limits as the setup; the world's own sensor values (noise and
    range included, no 24-bit quantisation) stand in for the DAQ, AC and IEPE channels through
    the simulated DAQ's coupling high-pass (which the FRF estimates divide out). Generators
    and amplifiers are the world's component models, switched directly.
    """

    def __init__(self, setup: TestSetup, world) -> None:
        self.setup, self.world = setup, world
        self.fs_hz = float(setup.daq.sample_rate_hz)
        self.passband_hz = setup.daq.passband_hz
        world.set_sample_rate(self.fs_hz)
        self.names = [c.name for c in setup.channels]
        self.rows = [c.input for c in setup.channels]
        self.sens = np.array([world.sensors[k].sensitivity_v_per_unit for k in self.rows])[:, None]
        gi = {g.name: i for i, g in enumerate(setup.generators)}
        self.out = [(gi[s.generator], s.channel) for s in setup.shakers]
        self.clock = 0
        from sim_devices.daq_sim import ac_highpass

        self._highpass = ac_highpass
        self.hp_state = {i: np.zeros(1) for i, c in enumerate(setup.channels) if c.coupling in AC_COUPLINGS}

    def _ch(self, j: int):
        g, ch = self.out[j]
        return self.world.generators[g].channels[ch - 1]

    def prepare(self) -> None:
        for j, a in enumerate(self.world.amplifiers):
            a.gain_v_per_v = next(x.gain_v_per_v for x in self.setup.amplifiers
                                  if x.name == self.setup.shakers[j].amplifier)
            a.request_enable()

    def sine(self, shaker: int, freq_hz: float, vpp: float) -> None:
        with self.world.lock:
            c = self._ch(shaker)
            c.function, c.freq_hz, c.vpp, c.output_on = "SIN", float(freq_hz), float(vpp), True

    def noise(self, shaker: int, vpp: float, bandwidth_hz: float) -> None:
        with self.world.lock:
            c = self._ch(shaker)
            c.function, c.vpp, c.noise_bw_hz, c.output_on = "NOIS", float(vpp), float(bandwidth_hz), True

    def arb(self, shaker: int, samples: np.ndarray, vpp: float) -> float:
        x = np.asarray(samples, float)
        scale = 1.0 / np.max(np.abs(x))
        with self.world.lock:
            c = self._ch(shaker)
            c.arb, c.arb_srate_hz, c.arb_pos = x * scale, self.fs_hz, 0.0
            c.function, c.vpp, c.output_on = "ARB", float(vpp), True
        return 0.5 * vpp * scale

    def drive_off(self, shaker: int) -> None:
        with self.world.lock:
            self._ch(shaker).output_on = False

    def acquire(self, n: int) -> np.ndarray:
        blk = self.world.advance(n)
        self.clock += n
        over = tuple(self.names[i] for i, k in enumerate(self.rows) if blk.overload[k])
        if over:
            raise SensorOverload(f"world: over range on {', '.join(over)} (samples clipped)", over)
        volts = blk.volts[self.rows]
        for i, state in self.hp_state.items():
            volts[i], self.hp_state[i] = self._highpass(volts[i], self.fs_hz, self.setup.daq.ac_corner_hz, state)
        return volts / self.sens

    def check(self) -> None:
        pass

    def line_check(self) -> None:
        pass

    def identities(self) -> dict:
        return {"world": "direct (no transports)"}

    def safe_state(self) -> list[str]:
        with self.world.lock:
            for g in self.world.generators:
                for c in g.channels:
                    c.output_on = False
            for a in self.world.amplifiers:
                a.disable()
        return []

    def close(self) -> None:
        self.safe_state()


def nominal_model(setup: TestSetup, mounted: bool = True) -> Model:
    """The analyst's model of a simulated-lab setup: its structure with every hidden
    ``[[sim.effects]]`` removed (what a nominal FE model gives).

    With ``mounted`` the stand is included as the lab has it (taken as known): DOFs are the
    structure's followed by one ``"stand@<dof>"`` per stand mass. Without, the structure alone.
    """
    # The hidden effects are left out of the model, but the setup is checked with them, as
    # `check` and `acquire` check it (an unknown effect type, a missing or non-finite value,
    # an unknown DOF): a setup the lab refuses must not give a model silently.
    build_world(setup)
    sim = {k: v for k, v in setup.sim.items() if k != "effects"}
    world = build_world(dataclasses.replace(setup, sim=sim))
    if not mounted:
        return Model(M=world.M_s, K=world.K_s, C=world.C_s, dofs=list(world.dofs))
    M, C, K, dofs = world.coupled_model()
    return Model(M=M, K=K, C=C, dofs=dofs)


EXAMPLE_SHAKERS = ("11+Z", "16+Z")
EXAMPLE_HIDDEN = {"type": "added_mass", "dof": "6+Z", "mass_kg": 0.25}


def example_setup_text() -> str:
    """The example test setup of the simulated lab (TOML): ``examples/setup_sim.toml``, the
    setup of ``ssidlab demo`` and the template of a new setup in ``ssidlab tui``."""
    from ssid.models.payload import INTERFACE_DOFS, Z_DOFS

    out = ['''# Example test setup for the simulated lab: the payload simulator on a three-post test stand.
#
#     ssidlab acquire examples/setup_sim.toml --sim --out run.h5
#
# Keys: docs/acquisition.md. Instrument addresses below are placeholders: with --sim they are
# replaced by the simulated instruments' endpoints; without it they must point at real ones.

[test]
name = "payload simulator on test stand, stepped sine"
operator = "ssidlab demo"

[output]
file = "run.h5"
uff = "run.uff"
raw_time = false

[daq]
interface = "socketcan"
channel = "can0"
sample_rate_hz = 4096          # 21 channels: 77 % of a 1/5 Mbit/s CAN FD bus
passband_fraction = 0.45       # anti-alias filter passband edge / fs: bands up to 1843 Hz

[[generators]]
name = "gen0"
url = "/dev/ttyUSB0"
max_vpp = 8.0
ramp_time_s = 0.05
''']
    for j in range(len(EXAMPLE_SHAKERS)):
        out.append(f'''[[amplifiers]]
name = "amp{j}"
host = "192.168.0.{10 + j}"
port = 502
gain_v_per_v = 2.0
''')
    for j, d in enumerate(EXAMPLE_SHAKERS):
        out.append(f'''[[shakers]]
dof = "{d}"
generator = "gen0"
channel = {j + 1}
amplifier = "amp{j}"
force_channel = "force {d}"
''')
    chans = ([(f"force {d}", d, "force", 22.5, 2.0) for d in EXAMPLE_SHAKERS]
             + [(f"acc {d}", d, "acceleration", 10.0, 5.0) for d in Z_DOFS]
             + [(f"load {d}", d, "reaction", 22.5, 5.0) for d in INTERFACE_DOFS])
    for k, (name, d, q, sens, rng) in enumerate(chans):
        out.append(f'''[[channels]]
name = "{name}"
input = {k}
dof = "{d}"
quantity = "{q}"
sensitivity_mv_per_unit = {sens}
range_volt = {rng}
''')
    out.append(f'''[excitation]
type = "stepped_sine"

[stepped_sine]
f_min_hz = 20.0
f_max_hz = 1500.0
n_lines = 40                   # coarse lines; the sweep refines near resonances
spacing = "log"
refine = 8                     # up to 8 finer lines per coarse step
max_change = 0.25              # target relative change of the response between lines
force_n = 2.0                  # force amplitude (peak) held by the level control
tolerance = 0.15
compression = 2.0
accuracy = 1e-3                # requested relative accuracy of each line
min_cycles = 8.0
min_dwell_s = 0.04
damping_guess = 0.01
max_settle_s = 10.0

[limits]
max_drive_vpp = 8.0
max_force_n = 50.0
max_accel_m_per_s2 = 400.0
max_reaction_n = 300.0

[quality]
min_coherence = 0.9

[sim]
structure = "payload"
damping_ratio = 0.02
noise = true
seed = 1
oversample = 4                 # the payload's modes reach 2.6 kHz: finer internal steps

[sim.stand]
stand_mass_kg = 20.0
stand_k_n_per_m = 2.0e6
stand_c_n_s_per_m = 400.0
ground_k_n_per_m = 5.0e6

[[sim.effects]]                # the hidden effect the nominal model lacks
type = "{EXAMPLE_HIDDEN['type']}"
dof = "{EXAMPLE_HIDDEN['dof']}"
mass_kg = {EXAMPLE_HIDDEN['mass_kg']}
''')
    return "\n".join(out)
