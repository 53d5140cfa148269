"""Instrument drivers, layered transport -> protocol -> device (pymeasure style).

==========================  ====================================================================
module                      what
==========================  ====================================================================
``drivers.errors``          the exception classes every driver raises
``drivers.serial_line``     transport: text lines over pyserial (device, pty or ``socket://``)
``drivers.scpi``            protocol: SCPI commands/queries with error-queue checks
``drivers.siggen``          device: two-channel arbitrary waveform generator (33500B-like)
``drivers.amplifier``       device: shaker power amplifier on Modbus TCP (pymodbus, async;
                            ``SyncShakerAmplifier`` for blocking callers)
``drivers.can_tcp``         transport: CAN FD over TCP, a python-can bus (sim-lab gateway)
``drivers.daq_protocol``    protocol: DAQ frames from ``ssidlab_daq.dbc`` (cantools), bus load,
                            stream reassembly (lost / duplicated / reordered frames)
``drivers.daq``             device: CAN FD DAQ front end (python-can)
``drivers.daq_receive``     the DAQ driver's receive path: frames polled and routed, the wait
                            for scans, the end of a finite acquisition
``drivers.interrupts``      Ctrl-C held back while a driver waits on a lock another thread takes
==========================  ====================================================================

Every device class has ``safe_state()`` (outputs off, amplifier disabled, acquisition
stopped) and is a context manager whose exit always tries to reach it; every read has a
timeout. Register map, SCPI command set and CAN frame layout: ``docs/drivers.md``.
Drivers import nothing from ``ssid``, ``daq``, ``tui`` or ``sim_devices``.
"""
