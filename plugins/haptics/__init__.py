"""Haptic outputs: the master devices a session sends the contact force to, and their emulators.

Plugins (``[haptic] name = ...``): ``null`` (no device), ``serial`` (``serial.py``: a master on a serial
port, in our framed protocol or Haply's Inverse3), ``hid`` (``hid.py``: a RawHID master in a configured
report layout). What both wire plugins share (their errors, the force clamp, the link event) is
``master.py``.

Serial, by layer: ``serial_port.py`` (the port, the link interface), ``hapticlab_link.py`` and
``framing.py`` (our protocol: conversation and bytes), ``inverse3_link.py`` and ``inverse3.py``
(Haply's). HID: ``hid_layout.py`` (report layouts), ``hid_transport.py`` (hidapi), ``hid_fake.py``
(a simulated master for tests and dry runs).

Emulator (``hapticlab emulate master``): ``master_emulator.py`` (the device on a pty),
``handle_motion.py`` (the hand's paths), ``master_emulator_cli.py`` (the command).
"""
