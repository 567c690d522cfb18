"""The host side of Haply's Inverse3 protocol (``inverse3.py``) over a serial port: wake-up, then force → state.

The Inverse3's replies have no framing and no sequence numbers: a reply is known by its code and
length alone, so after a bad one the link drops what is in flight and starts the next exchange clean.
"""

from __future__ import annotations

import time

import numpy as np

from hapticlab.plugins.haptics import inverse3
from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError
from hapticlab.plugins.haptics.serial_port import Reading, SerialPort


class Inverse3Link:
    """Haply's Inverse3 protocol (``inverse3.py``): wake-up, then force → end-effector state exchanges."""

    def __init__(self, port: SerialPort, read_timeout: float):
        self.port, self.read_timeout = port, read_timeout
        self.max_force: float | None = None  # the Inverse3 does not report one
        self.counters = {"bad_replies": 0, "truncated_replies": 0}
        self.owed = 0  # replies to posted forces not yet read

    def post(self, force_D: np.ndarray) -> None:
        """Write a force request without reading its reply (the next exchange reads and drops it)."""
        self.port.write(inverse3.pack_force_request(force_D))
        self.owed += 1

    def _read_exactly(self, size: int, deadline: float) -> bytes:
        data = b""
        while len(data) < size:
            chunk = self.port.read(size - len(data), deadline)
            if not chunk:
                break
            data += chunk
        return data

    def handshake(self, timeout_s: float) -> str:
        where = f"haptic.port {self.port.name}"
        deadline = time.monotonic() + timeout_s
        self.port.discard_input()
        reply = b""
        while time.monotonic() < deadline:
            self.port.write(inverse3.WAKEUP_REQUEST)
            reply = self._read_exactly(inverse3.DEVICE_INFO_SIZE, min(deadline, time.monotonic() + 0.5))
            if reply:
                reply += self._read_exactly(inverse3.DEVICE_INFO_SIZE - len(reply), time.monotonic() + 0.05)
                break
        if not reply:
            raise MasterOpenError(
                f"{where}: no reply to the Inverse3 wake-up (0x0A) within {timeout_s:g} s "
                "(is it an Inverse3, powered, and not held by another program?)"
            )
        try:
            info = inverse3.DeviceInfo.unpack(reply)
        except ValueError as exc:
            raise MasterOpenError(f"{where}: not an Inverse3 answer to the wake-up: {exc}") from None
        return (
            f"Haply Inverse3 device {info.device_id} ({info.device_id_ext}), model {info.model}, "
            f"hardware {info.hardware_version}, firmware {info.firmware_version}"
        )

    def exchange(self, force_D: np.ndarray) -> Reading | None:
        self.port.write(inverse3.pack_force_request(force_D))
        owed, self.owed = self.owed, 0
        if owed:  # the replies to posted forces come first: read past them
            self._read_exactly(owed * inverse3.STATE_SIZE, time.monotonic() + self.read_timeout)
        reply = self._read_exactly(inverse3.STATE_SIZE, time.monotonic() + self.read_timeout)
        if not reply:
            raise MasterLostError(f"{self.port.name}: no reply within {self.read_timeout * 1e3:g} ms")
        if len(reply) < inverse3.STATE_SIZE or reply[0] != inverse3.END_EFFECTOR_STATE:
            # no framing to resynchronise on: drop what is in flight, the next exchange starts clean
            self.counters["truncated_replies" if len(reply) < inverse3.STATE_SIZE else "bad_replies"] += 1
            self.port.discard_input()
            return None
        p_DoHo_D, v_DHo_D = inverse3.unpack_state(reply)
        if not (np.isfinite(p_DoHo_D).all() and np.isfinite(v_DHo_D).all()):
            self.counters["bad_replies"] += 1
            return None
        return Reading(p_DoHo_D, v_DHo_D)
