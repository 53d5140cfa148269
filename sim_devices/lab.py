"""The simulated lab: one world, and every instrument on its own real transport.

:class:`SimLab` starts a SCPI generator per world generator (pty or TCP socket), a Modbus
TCP amplifier per shaker (127.0.0.1, ephemeral ports), the CAN FD DAQ node on a python-can
virtual bus, and optionally a CAN-over-TCP gateway so that another process can reach the
bus. :meth:`SimLab.endpoints` tells a driver (or the app) where to connect.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence

from ssid.models import example_system

from .amp_sim import AmpServerThread, SimAmplifier
from .can_gateway import CanTcpGateway
from .components import SensorSpec, ShakerSpec, StandSpec
from .daq_sim import SimDaq
from .effects import Effect
from .siggen_sim import SimSignalGenerator
from .world import World

__all__ = ["SimLab", "example_world"]


def example_world(
    *,
    shaker_dofs: Sequence[str] = ("1+Z", "8+Z"),
    stand: bool = False,
    effects: Sequence[Effect] = (),
    noise: bool = True,
    seed: int = 0,
) -> World:
    """The bundled 14-DOF example structure with shakers, force gauges and accelerometers.

    Sensors: one force gauge per shaker (22.5 mV/N), then an accelerometer
    (10 mV/(m/s^2)) at each of the 14 DOFs, then a load cell (22.5 mV/N) per reaction DOF
    when ``stand`` is set (reactions at ``"14+Z"``). With two shakers that is 16 channels.
    Shaker ``j`` is driven by generator ``j // 2`` output ``j % 2 + 1``.
    """
    M, C, K, dofs = example_system(14, seed=1)
    shakers = [ShakerSpec(d, generator=j // 2, channel=j % 2 + 1) for j, d in enumerate(shaker_dofs)]
    sensors = [SensorSpec(f"force {d}", "force", j, 0.0225) for j, d in enumerate(shaker_dofs)]
    sensors += [SensorSpec(f"acc {d}", "acceleration", d, 0.010) for d in dofs]
    stand_spec = StandSpec(("14+Z",)) if stand else None
    if stand_spec:
        sensors += [SensorSpec(f"load {r}", "reaction", r, 0.0225) for r in stand_spec.reactions]
    return World(M, C, K, dofs, shakers=shakers, sensors=sensors, stand=stand_spec, effects=effects,
                 noise=noise, seed=seed)


class SimLab:
    """All simulated instruments around one world.

    Parameters
    ----------
    world : World
    generator_transport : {"pty", "tcp"}
        How the SCPI generators are reached.
    can_channel : str, optional
        Virtual CAN channel name (default: a unique name, so that labs do not cross-talk).
    speed : float or None
        DAQ pacing: None as fast as possible, 1.0 real time.
    gateway : bool
        Also serve the CAN bus over TCP on 127.0.0.1 (for other processes).
    gateway_port, amp_ports : int, list of int
        Fixed ports (0 or None: ephemeral).
    ac_corner_hz : float, optional
        The DAQ's AC/IEPE coupling corner (default its own, ``daq_sim.AC_CORNER_HZ``).
    """

    def __init__(
        self,
        world: World,
        *,
        generator_transport: str = "pty",
        can_channel: str | None = None,
        speed: float | None = None,
        gateway: bool = False,
        gateway_port: int = 0,
        amp_ports: Sequence[int] | None = None,
        ac_corner_hz: float | None = None,
    ) -> None:
        self.world = world
        self.generator_transport = generator_transport
        self.can_channel = can_channel or f"ssidlab-{uuid.uuid4().hex[:8]}"
        self.speed = speed
        self.want_gateway = gateway
        self.gateway_port = gateway_port
        self.amp_ports = list(amp_ports) if amp_ports else [0] * len(world.amplifiers)
        self.daq_options = {} if ac_corner_hz is None else {"ac_corner_hz": float(ac_corner_hz)}
        self.generators: list[SimSignalGenerator] = []
        self.amplifiers: list[SimAmplifier] = []
        self.daq: SimDaq | None = None
        self.gateway: CanTcpGateway | None = None
        self._amp_host: AmpServerThread | None = None

    def start(self) -> SimLab:
        try:
            for g in range(len(self.world.generators)):
                self.generators.append(SimSignalGenerator(self.world, g, self.generator_transport, seed=g).start())
            self._amp_host = AmpServerThread()
            for j, model in enumerate(self.world.amplifiers):
                self.amplifiers.append(SimAmplifier(model, self._amp_host, self.amp_ports[j], name=f"amp{j}",
                                                   serial=52001 + j).start())
            self.daq = SimDaq(self.world, self.can_channel, speed=self.speed, serial=self.world.fingerprint(),
                              **self.daq_options).start()
            if self.want_gateway:
                self.gateway = CanTcpGateway(self.can_channel, self.gateway_port).start()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Stop every simulator (each attempted even if another fails)."""
        errors = []
        for stop in ([g.stop for g in self.generators] + ([self.gateway.stop] if self.gateway else [])
                     + ([self.daq.stop] if self.daq else []) + [a.stop for a in self.amplifiers]
                     + ([self._amp_host.stop] if self._amp_host else [])):
            try:
                stop()
            except Exception as exc:  # keep stopping the others
                errors.append(exc)
        self.generators, self.amplifiers, self.daq, self.gateway, self._amp_host = [], [], None, None, None
        if errors:
            raise errors[0]

    def endpoints(self) -> dict:
        """Where each instrument listens (JSON-serialisable)."""
        return {
            "generators": [g.url for g in self.generators],
            "amplifiers": [{"host": a.host, "port": a.port, "device_id": 1} for a in self.amplifiers],
            "daq": {
                "can_channel": self.can_channel,
                "gateway": f"127.0.0.1:{self.gateway.port}" if self.gateway else None,
                "inputs": [s.name for s in self.world.sensors],
            },
        }

    def __enter__(self) -> SimLab:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
