"""Simulated instruments on real transports, driven by one physics world (``ssid.models`` physics).

==============================  ================================================================
module                          what
==============================  ================================================================
``sim_devices.world``           the world: generator -> amplifier -> shaker (back-EMF) ->
                                structure (any M, C, K; stand; hidden effects) -> sensors, exact
                                modal time integration in sample time
``sim_devices.world_errors``     why a world cannot be built (``WorldError``; ``EffectError``
                                names the hidden effect at fault and its parameter)
``sim_devices.components``      shaker, stand, sensor specs; generator and amplifier models
``sim_devices.effects``         hidden effects (added mass, springs, damper, attached oscillator)
``sim_devices.siggen_sim``      SCPI generator on a pseudo-terminal or a TCP socket
``sim_devices.amp_sim``         amplifier as a pymodbus Modbus TCP server
``sim_devices.daq_sim``         CAN FD DAQ node on a python-can virtual bus (the world's clock)
``sim_devices.can_gateway``     the virtual CAN bus over TCP, for other processes
``sim_devices.lab``             ``SimLab``: every simulator around one world; ``example_world``
``sim_devices.cli``             ``ssidlab sim-lab`` / ``python -m sim_devices``
==============================  ================================================================

Everything listens on 127.0.0.1 only. Each simulator has fault injection for tests
(``inject(...)``). Simulators import ``ssid`` physics only, never ``drivers``, ``daq`` or ``tui``.
"""
