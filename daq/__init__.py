"""Acquisition: excitation scheduling, FRF estimation, safety limits, crash-safe storage.

``ssidlab acquire SETUP.toml [--sim]`` runs :func:`daq.run.run_test`; the user guide is
``docs/acquisition.md``.

==========================  ====================================================================
module                      what
==========================  ====================================================================
``daq.setup``               the TOML test setup: parsing, validation (errors name the key)
``daq.toml_table``          one TOML table read with types and ranges checked (setup, ``[sim]``)
``daq.rig``                 ``Rig``: the instruments behind one interface; ``InstrumentRig``
                            opens the drivers (generator, amplifiers, CAN FD DAQ)
``daq.estimate``            harmonic least-squares fit, multi-input solve ``H = X_A X_F^-1``,
                            Welch spectra, H1 / H2 / Hv, ordinary and multiple coherence
``daq.schedule``            stepped-sine line grid and the adaptive sweep (refines near
                            resonances on the fly; one sweep per shaker)
``daq.sine_line``           one stepped-sine line: level control, settling, dwell
``daq.steady_state``        the transient left after a change (stepped-sine windows, periods
                            of periodic and burst random), bounded from the data; noise floor
``daq.stepped_sine``        the stepped-sine run: sub-lines -> FRF lines, quality, blanking,
                            resume by replaying the records
``daq.random_run``          continuous, periodic and burst random (MIMO), spectral averaging
``daq.storage``             the run file: contract FRF view + ``/acq`` records, flushed per
                            line, finalised atomically
``daq.run_file_replace``    the run file replaced whole, never restructured in place: the
                            edited copy, the compact file at the end, killed runs' leftovers
``daq.safety``              limits (abort the line), faults (stop the run), messages
``daq.run``                 a whole run: every exit path ends in the safe state; what a
                            resume may change (the DAQ input ranges)
``daq.control``             pause / resume between lines; the run's events for a UI
``daq.check``               connection check: every instrument opened, identified, released
``daq.thread_stacks``       every thread's stack to stderr (a run that does not stop), GIL held
UFF 58 export               by ``daq.run`` through ``ssid.exchange.write_uff_frf``
``daq.simlab``              the only bridge to ``sim_devices``: the ``--sim`` lab for a setup,
                            ``WorldRig`` for benchmarks
==========================  ====================================================================

Dependencies: ``daq -> drivers``, ``daq -> ssid``; ``sim_devices`` only in ``daq.simlab``.
"""
