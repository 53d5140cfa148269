"""Exceptions raised by the instrument drivers.

Every failure a lab run can meet has its own class, so that acquisition code can decide
between retry, recovery and abort, and every message says which instrument and what to do.
"""

from __future__ import annotations

__all__ = [
    "AmplifierFault",
    "BusCapacityError",
    "BusOff",
    "ConnectionLost",
    "DeviceError",
    "FramesLost",
    "HeartbeatLost",
    "InstrumentError",
    "InstrumentTimeout",
    "InterlockOpen",
    "ProtocolError",
    "RangeError",
    "SensorOverload",
    "StreamError",
]


class InstrumentError(Exception):
    """Base class of every driver error."""


class InstrumentTimeout(InstrumentError, TimeoutError):
    """No (complete) reply within the timeout: the instrument is silent or the line is broken."""


class ProtocolError(InstrumentError):
    """A reply that does not follow the protocol (garbage, wrong frame, bad checksum)."""


class DeviceError(InstrumentError):
    """The instrument reported an error (SCPI error queue, Modbus exception, DAQ status)."""


class RangeError(InstrumentError, ValueError):
    """A setting outside the instrument's (or the configured safety) range; nothing was sent."""


class InterlockOpen(InstrumentError):
    """The amplifier's interlock (door, E-stop) is open: it cannot be enabled."""


class AmplifierFault(InstrumentError):
    """The amplifier reports a latched fault (over-temperature, over-travel, ...)."""

    def __init__(self, message: str, code: int = 0) -> None:
        super().__init__(message)
        self.code = code


class HeartbeatLost(AmplifierFault):
    """The amplifier's heartbeat counter stopped or its status could not be read."""


class ConnectionLost(InstrumentError):
    """The link to the instrument dropped."""


class BusCapacityError(InstrumentError, ValueError):
    """The requested streaming load does not fit on the CAN FD bus."""


class StreamError(InstrumentError):
    """The sample stream is broken (gap, stall, bad frame)."""


class FramesLost(StreamError):
    """Data frames were lost: the stream has a gap."""


class BusOff(StreamError):
    """The CAN controller went bus-off (or the DAQ node is silent)."""


class SensorOverload(InstrumentError):
    """A channel exceeded its input range; its samples are clipped."""

    def __init__(self, message: str, channels: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.channels = channels
