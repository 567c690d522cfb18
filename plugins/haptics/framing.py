"""hapticlab's framed binary protocol for DIY serial haptic masters (Hapkit class), version 1.

The specification is ``docs/serial-protocol.md``; the device side is
``firmware/hapticlab_master/hapticlab_master.ino``. This module is the pure
byte level, shared by the host's link (``hapticlab_link.py``) and the emulator
(``master_emulator.py``): no I/O.

A frame::

    0xA5 0x5A | type u8 | seq u8 | len u8 | payload (len bytes) | crc u16 LE

The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, no
final XOR; check value 0x29B1 over ``b"123456789"``) over type, seq, len and
the payload. Every multi-byte field is little-endian; forces in N, positions
in m, velocities in m/s.

:class:`FrameDecoder` hunts for frames in a byte stream: bytes before a sync
pair are skipped (counted as garbage), and a candidate frame whose CRC fails
is rejected (counted) and the hunt resumes one byte after its sync, so a good
frame hidden behind garbage or a broken frame is still found.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

PROTOCOL_VERSION = 1
SYNC = b"\xa5\x5a"
HEADER_SIZE = 5  # sync (2), type, seq, len
CRC_SIZE = 2
MAX_PAYLOAD = 64

# message types: host → device below 0x80, device → host at and above
HELLO = 0x01
FORCE = 0x02
HEARTBEAT = 0x03
HELLO_ACK = 0x81
STATE = 0x82
NAK = 0xFF

# NAK codes
NAK_CRC = 1
NAK_UNKNOWN_TYPE = 2
NAK_BAD_LENGTH = 3
NAK_VERSION = 4
NAK_NOT_READY = 5  # a FORCE or HEARTBEAT before the HELLO (the device restarted)
NAK_NAMES = {
    NAK_CRC: "bad CRC",
    NAK_UNKNOWN_TYPE: "unknown message type",
    NAK_BAD_LENGTH: "bad payload length",
    NAK_VERSION: "protocol version not supported",
    NAK_NOT_READY: "no HELLO yet (device restarted?)",
}

# STATE status bits
STATUS_WATCHDOG = 1 << 0  # the device zeroed its force: no valid host frame within the watchdog time
STATUS_CLAMPED = 1 << 1  # the device clamped the commanded force to its own maximum
STATUS_FAULT = 1 << 2  # motor driver fault, over-temperature, ...: the device renders no force

HELLO_FORMAT = struct.Struct("<BH")  # version, watchdog ms (0: off)
HELLO_ACK_FORMAT = struct.Struct("<BHBff")  # version, device id, firmware version, max force N, max rate Hz
FORCE_FORMAT = struct.Struct("<3f")  # force_D, N
STATE_FORMAT = struct.Struct("<B3f3fHB")  # ack seq, p_DoHo_D m, v_DHo_D m/s, buttons, status
NAK_FORMAT = struct.Struct("<BB")  # seq of the rejected frame (0 when unknown), code

PAYLOAD_SIZES = {
    HELLO: HELLO_FORMAT.size,
    FORCE: FORCE_FORMAT.size,
    HEARTBEAT: 0,
    HELLO_ACK: HELLO_ACK_FORMAT.size,
    STATE: STATE_FORMAT.size,
    NAK: NAK_FORMAT.size,
}
"""The payload length of each message type in version 1, bytes."""


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16_ccitt_false(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF, no reflection, no final XOR)."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


def encode_frame(kind: int, seq: int, payload: bytes = b"") -> bytes:
    """One frame on the wire: sync, type, seq (mod 256), length, payload, CRC (LE)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    body = bytes((kind, seq & 0xFF, len(payload))) + payload
    return SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame: its type, sequence number and payload."""

    kind: int
    seq: int
    payload: bytes


class FrameDecoder:
    """Finds frames in a byte stream that may hold garbage and broken frames.

    Attributes:
        crc_errors: candidate frames rejected for a wrong CRC.
        garbage_bytes: bytes skipped while hunting for a frame (noise, a
            rejected frame's body, a length beyond ``MAX_PAYLOAD``).
    """

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.crc_errors = 0
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[Frame]:
        """Every complete frame in the stream so far, in order; an incomplete tail waits for more bytes."""
        buf = self.buffer
        buf += data
        frames: list[Frame] = []
        while True:
            start = buf.find(SYNC)
            if start < 0:  # keep a trailing 0xA5: it may be the first half of a sync pair
                keep = 1 if buf.endswith(SYNC[:1]) else 0
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return frames
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < HEADER_SIZE:
                return frames
            length = buf[4]
            if length > MAX_PAYLOAD:
                self.garbage_bytes += 1
                del buf[:1]
                continue
            end = HEADER_SIZE + length + CRC_SIZE
            if len(buf) < end:
                return frames
            body = bytes(buf[2 : HEADER_SIZE + length])
            if crc16_ccitt_false(body) != int.from_bytes(buf[end - CRC_SIZE : end], "little"):
                self.crc_errors += 1
                self.garbage_bytes += 1
                del buf[:1]  # hunt again from the next byte: a good frame may start inside this one
                continue
            frames.append(Frame(body[0], body[1], body[3:]))
            del buf[:end]

    def pending(self) -> int:
        """Bytes held back as the start of a frame not yet complete."""
        return len(self.buffer)


# ---------------------------------------------------------------- messages


@dataclass(frozen=True, slots=True)
class HelloAck:
    """The device's answer to HELLO.

    Attributes:
        version: the protocol version the device speaks.
        device_id: the device's identifier.
        firmware_version: the firmware's own version number.
        max_force: the largest force the device renders, N.
        max_rate_hz: the fastest command rate the device keeps up with, Hz.
    """

    version: int
    device_id: int
    firmware_version: int
    max_force: float
    max_rate_hz: float

    def pack(self) -> bytes:
        return HELLO_ACK_FORMAT.pack(
            self.version, self.device_id, self.firmware_version, self.max_force, self.max_rate_hz
        )

    @classmethod
    def unpack(cls, payload: bytes) -> HelloAck:
        return cls(*HELLO_ACK_FORMAT.unpack(payload))


@dataclass(frozen=True, slots=True)
class State:
    """The device's state, sent in reply to FORCE and HEARTBEAT.

    Attributes:
        ack_seq: the sequence number of the host frame this answers.
        p_DoHo_D: (3,) handle position in the device frame D, m (CRTK ``measured_cp``).
        v_DHo_D: (3,) handle velocity in D, m/s (CRTK ``measured_cv``).
        buttons: bit mask of pressed buttons.
        status: ``STATUS_*`` bits.
    """

    ack_seq: int
    p_DoHo_D: np.ndarray
    v_DHo_D: np.ndarray
    buttons: int
    status: int

    def pack(self) -> bytes:
        return STATE_FORMAT.pack(
            self.ack_seq,
            *np.asarray(self.p_DoHo_D, np.float32).tolist(),
            *np.asarray(self.v_DHo_D, np.float32).tolist(),
            self.buttons,
            self.status,
        )

    @classmethod
    def unpack(cls, payload: bytes) -> State:
        ack, px, py, pz, vx, vy, vz, buttons, status = STATE_FORMAT.unpack(payload)
        return cls(ack, np.array([px, py, pz]), np.array([vx, vy, vz]), buttons, status)


def pack_hello(watchdog_s: float) -> bytes:
    """HELLO's payload: our protocol version and the device watchdog time (s, 0 = off, at most 65.535 s)."""
    return HELLO_FORMAT.pack(PROTOCOL_VERSION, min(round(watchdog_s * 1000), 0xFFFF))


def pack_force(force_D: np.ndarray) -> bytes:
    """FORCE's payload: (3,) force in D, N, as three float32 (already clamped and finite)."""
    return FORCE_FORMAT.pack(*np.asarray(force_D, np.float32).tolist())


def unpack_force(payload: bytes) -> np.ndarray:
    """(3,) float32 force of a FORCE payload, N, exactly as it was on the wire."""
    return np.frombuffer(payload, dtype="<f4", count=3).copy()
