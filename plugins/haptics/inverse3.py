"""The Haply Inverse3 serial protocol: the messages hapticlab uses, byte for byte.

The Inverse3 speaks unframed binary over USB CDC serial: a one-byte command
code, then a fixed-size payload; the device answers each request with a
one-byte response code and a fixed-size payload. No sync, no checksum: a
reply is recognised by its code and its length alone.

=============================  =======  ==========================================================
message                        code     payload
=============================  =======  ==========================================================
wake-up (host → device)        0x0A     none
device info (device → host)    0x0B     device_id u16, model u8, hardware u8, firmware u8,
                                        device_id_ext 16 bytes (UUID): 21 bytes
end-effector force (host →)    0x2A     force x, y, z: 3 float32 LE, N
end-effector state (→ host)    0x2B     position x, y, z (m), velocity x, y, z (m/s): 6 float32 LE
=============================  =======  ==========================================================

Source of the layout: Haply's C++ HardwareAPI header ``Inverse3.h`` (Haply
Robotics), whose command constants are ``HC_DEVICE_WAKEUP = 0x0A``,
``HC_DEVICE_ID = 0x0B``, ``HC_END_EFFECTOR_FORCE = 0x2A``,
``HC_END_EFFECTOR_STATE = 0x2B`` and whose ``DeviceInfoResponse`` is
``{uint16_t device_id; uchar device_model_number; uchar hardware_version;
uchar firmware_version; UUID device_id_ext}``, ``EndEffectorForceRequest``
``{float force[3]}`` and ``EndEffectorStateResponse`` ``{float position[3];
float velocity[3]}``. Haply's own Python client, ``HaplyHardwareAPI`` 0.1.13
(C++ core 0.2.8), agrees on the byte counts and order over a pseudo-terminal
(``tests/plugins/haptics/test_inverse3.py``): ``Inverse3.device_wakeup_dict()``
writes exactly ``0a`` and waits for 22 bytes (a 6-byte answer without the UUID
times out), and ``end_effector_force([1.5, -2.25, 3.0])`` writes
``2a 0000c03f 000010c0 00004040`` and reads 25 bytes. Units, from
Haply's "Developing with Inverse3" (docs.haply.co/docs/developing-with-inverse3,
Cartesian control): force in N, position in m, velocity in m/s, in the
device's right-handed frame with its origin on the mounting plate (our D).

Haply's newer software talks to the device through its "Inverse Service"
(WebSocket), which then owns the serial port: stop that service before
opening the port here. (The plugin locks the port with ``flock``, so a
second hapticlab is refused by name; a program that does not lock it is not.)
"""

from __future__ import annotations

import struct
import uuid
from dataclasses import dataclass

import numpy as np

WAKEUP = 0x0A
DEVICE_INFO = 0x0B
END_EFFECTOR_FORCE = 0x2A
END_EFFECTOR_STATE = 0x2B

DEVICE_INFO_FORMAT = struct.Struct("<HBBB16s")
FORCE_FORMAT = struct.Struct("<3f")
STATE_FORMAT = struct.Struct("<6f")

WAKEUP_REQUEST = bytes((WAKEUP,))
DEVICE_INFO_SIZE = 1 + DEVICE_INFO_FORMAT.size  # 22 bytes on the wire
FORCE_REQUEST_SIZE = 1 + FORCE_FORMAT.size  # 13
STATE_SIZE = 1 + STATE_FORMAT.size  # 25


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """The answer to the wake-up: who the device is.

    Attributes:
        device_id: the short device id (u16; Haply deprecates it for ``device_id_ext``).
        model: device model number.
        hardware_version, firmware_version: version numbers.
        device_id_ext: the device's UUID.
    """

    device_id: int
    model: int
    hardware_version: int
    firmware_version: int
    device_id_ext: uuid.UUID

    def pack(self) -> bytes:
        """The device info reply on the wire, code included (22 bytes)."""
        return bytes((DEVICE_INFO,)) + DEVICE_INFO_FORMAT.pack(
            self.device_id, self.model, self.hardware_version, self.firmware_version, self.device_id_ext.bytes
        )

    @classmethod
    def unpack(cls, reply: bytes) -> DeviceInfo:
        """Parse a 22-byte device info reply (code included); ValueError naming what is wrong."""
        if len(reply) != DEVICE_INFO_SIZE or reply[0] != DEVICE_INFO:
            raise ValueError(
                f"expected a {DEVICE_INFO_SIZE}-byte device info reply starting 0x0B, "
                f"got {len(reply)} byte(s) {reply[:8].hex(' ')}{' ...' if len(reply) > 8 else ''}"
            )
        device_id, model, hardware, firmware, ext = DEVICE_INFO_FORMAT.unpack(reply[1:])
        return cls(device_id, model, hardware, firmware, uuid.UUID(bytes=ext))


def pack_force_request(force_D: np.ndarray) -> bytes:
    """The end-effector force request (13 bytes): (3,) force in D, N, as float32."""
    return bytes((END_EFFECTOR_FORCE,)) + FORCE_FORMAT.pack(*np.asarray(force_D, np.float32).tolist())


def unpack_force_request(request: bytes) -> np.ndarray:
    """(3,) float32 force of a 13-byte force request, N, exactly as it was on the wire."""
    return np.frombuffer(request, dtype="<f4", count=3, offset=1).copy()


def pack_state(p_DoHo_D: np.ndarray, v_DHo_D: np.ndarray) -> bytes:
    """The end-effector state reply (25 bytes): position (m) and velocity (m/s) in D, as float32."""
    values = np.concatenate([np.asarray(p_DoHo_D, np.float32), np.asarray(v_DHo_D, np.float32)])
    return bytes((END_EFFECTOR_STATE,)) + STATE_FORMAT.pack(*values.tolist())


def unpack_state(reply: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(p_DoHo_D m, v_DHo_D m/s) of a 25-byte state reply; ValueError naming what is wrong."""
    if len(reply) != STATE_SIZE or reply[0] != END_EFFECTOR_STATE:
        raise ValueError(
            f"expected a {STATE_SIZE}-byte end-effector state starting 0x2B, "
            f"got {len(reply)} byte(s) starting {reply[:4].hex(' ') or 'nothing'}"
        )
    values = np.array(STATE_FORMAT.unpack(reply[1:]))
    return values[:3], values[3:]
