"""Hardware link layer: the GNC FMUs against a real vessel (or its emulator) over NMEA 0183 and CAN.

- ``link.HardwareLink``: a master unit with the Plant FMU's names (inputs ``n_cmd_i``; outputs
  ``meas_*``, ``*_count``, ``n_i`` and link status), paced to the wall clock;
- ``nmea`` / ``canbus``: the codecs (pynmea2; cantools with the DBC files shipped here);
- ``transport``: pyserial and python-can ports that never block and reopen when lost;
- ``pacing.Pacer``: real-time pacing with real-time factor and jitter statistics;
- ``emulator``: ``seafmu emulate`` — the plant model in real time behind the same protocols;
- ``drive``: the drive-side command check (alive counter, command timeout, enable edge) the
  emulator implements and a real drive must; ``plausibility``: limits of every decoded value;
- ``link_fmu``: the link as an FMI 2.0 FMU; ``recording``: raw traffic and a maneuver trial;
- ``profile``: hardware profiles (``profiles/*.yaml``). Guide: docs/hardware.md.
"""
