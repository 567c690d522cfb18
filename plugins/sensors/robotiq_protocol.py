"""The Robotiq FT 300's serial protocol: Modbus RTU for its registers, a 100 Hz stream for its readings.

What the FT 300 instruction manual (section 4.4, "Serial Communication") states, and what this
module encodes:

* Modbus RTU at 19200 bit/s, 8 data bits, no parity, 1 stop bit; slave id 9. FC03 (read holding
  registers) reads the sensor's information; FC16 (preset multiple registers) starts the stream.
* Registers: 180–185 Fx, Fy, Fz (N = value/100) and Mx, My, Mz (N·m = value/1000), signed 16-bit;
  190–192 acceleration (g = value/1000); 510–513 the serial number; 514 the production year.
* The stream: writing 0x0200 to register 410 starts it. The sensor then sends 16-byte frames at
  100 Hz, ``0x20 0x4E``, six signed 16-bit values least significant byte first (Fx, Fy, Fz at 1/100
  N, Mx, My, Mz at 1/1000 N·m), and the CRC-16/Modbus of the first 14 bytes, least significant byte
  first. While it streams it answers no Modbus request. A series of 0xFF bytes stops it ("about
  0.5 s, 50 times").

What Robotiq's own driver (``rq_sensor_com.c`` in ros-industrial's robotiq repository, BSD) adds and
the manual's pages leave out: the firmware version is registers 500–502 (three ASCII letters and
three version numbers, one per byte, most significant byte first: ``FTS-3.0.4``); the serial number
is three ASCII letters in registers 510–511 and a 32-bit number in 512 (low word) and 513 (high
word), written ``FTS-0042``; the sensor answers the FC16 that starts the stream with the usual
8-byte FC16 echo before its first frame; 80 ms without a byte means the stream has stopped.
"""

from __future__ import annotations

import struct

import numpy as np

BAUDRATE = 19200
"""The sensor's serial rate, bit/s (8N1)."""
SLAVE_ID = 9
"""The sensor's Modbus slave id."""
STREAM_RATE_HZ = 100.0
"""The stream's frame rate, Hz."""
REG_FORCE = 180
"""Fx, Fy, Fz, Mx, My, Mz: six signed 16-bit registers, 1/100 N and 1/1000 N·m."""
REG_ACCELERATION = 190
"""Ax, Ay, Az: three signed 16-bit registers, 1/1000 g (the manual's table; the emulator has none)."""
REG_STREAM = 410
"""Writing ``STREAM_START`` here (FC16) starts the stream."""
STREAM_START = 0x0200
REG_FIRMWARE = 500
"""Firmware version, three registers (Robotiq's driver)."""
REG_SERIAL = 510
"""Serial number, four registers."""
REG_YEAR = 514
"""Production year, one register."""
HEADER = b"\x20\x4e"
"""The first two bytes of every stream frame."""
FRAME_SIZE = 16
"""Bytes per stream frame: header, six int16 values, CRC."""
STOP_BYTE = 0xFF
STOP_COUNT = 50
"""How many 0xFF bytes stop the stream (the manual's "50 times")."""
SI_PER_COUNT = np.array([0.01, 0.01, 0.01, 0.001, 0.001, 0.001])
"""(6,) N per count for Fx, Fy, Fz, N·m per count for Mx, My, Mz, in the stream and registers 180–185."""
RANGE_FORCE_N = 300.0
"""The FT 300's rated range per force axis, ±N."""
RANGE_TORQUE_NM = 30.0
"""Its rated range per torque axis, ±N·m."""
INT16 = 32767
FC_READ = 3
FC_READ_INPUT = 4
FC_WRITE_MANY = 16

_VALUES = struct.Struct("<6h")


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_TABLE = _crc_table()


def crc16(data: bytes | bytearray | memoryview) -> int:
    """The CRC-16/Modbus of ``data`` (reflected polynomial 0xA001, initial value 0xFFFF)."""
    crc = 0xFFFF
    for byte in data:
        crc = (crc >> 8) ^ _TABLE[(crc ^ byte) & 0xFF]
    return crc


def with_crc(body: bytes) -> bytes:
    """``body`` with its CRC-16/Modbus appended, least significant byte first (a Modbus RTU message)."""
    return body + crc16(body).to_bytes(2, "little")


def counts_of(force_S: np.ndarray, torque_S: np.ndarray) -> np.ndarray:
    """(N, 6) int64 counts of readings in N and N·m, rounded, clipped to a signed 16-bit value (±327.67 N,
    ±32.767 N·m: what the sensor's wire can carry) and 0 for a reading that is not a number."""
    wrench = np.concatenate([np.atleast_2d(force_S), np.atleast_2d(torque_S)], axis=1)
    counts = np.rint(np.nan_to_num(wrench / SI_PER_COUNT, nan=0.0, posinf=INT16, neginf=-INT16))
    return np.clip(counts, -INT16, INT16).astype(np.int64)


def encode_frame(counts: np.ndarray | list[int]) -> bytes:
    """One 16-byte stream frame of six counts (Fx..Mz)."""
    return with_crc(HEADER + _VALUES.pack(*(int(c) for c in counts)))


def text_registers(letters: str, numbers: tuple[int, ...]) -> list[int]:
    """Registers holding three ASCII ``letters`` then byte ``numbers``, most significant byte first (the
    firmware version's layout: ``text_registers("FTS", (3, 0, 4))``)."""
    data = letters.encode("ascii") + bytes(numbers)
    data += b"\0" * (len(data) % 2)
    return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]


def firmware_version(registers: list[int]) -> str:
    """Registers 500–502 as Robotiq's driver writes them, e.g. ``FTS-3.0.4``."""
    b = b"".join(r.to_bytes(2, "big") for r in registers[:3])
    return f"{b[:3].decode('latin-1')}-{b[3]}.{b[4]}.{b[5]}"


def serial_number_registers(serial: str) -> list[int]:
    """Registers 510–513 of a serial number ``LLL-NNNN`` (three letters, a number below 2³²)."""
    letters, _, number = serial.partition("-")
    if len(letters) != 3 or not letters.isascii() or not number.isdigit() or int(number) >= 2**32:
        raise ValueError(f"a serial number is three letters, '-' and a number, e.g. FTS-0042; got {serial!r}")
    head = text_registers(letters, (0,))
    value = int(number)
    return [*head, value & 0xFFFF, value >> 16]


def serial_number(registers: list[int]) -> str:
    """Registers 510–513 as Robotiq's driver writes them (``FTS-0042``; ``UNKNOWN`` when the number is 0)."""
    value = (registers[3] << 16) | registers[2]
    if value == 0:
        return "UNKNOWN"
    letters = (registers[0].to_bytes(2, "big") + bytes((registers[1] >> 8,))).decode("latin-1")
    return f"{letters}-{value:04d}"


class StreamParser:
    """Stream frames out of the bytes a port delivers, however they are cut: synchronised on the header,
    each frame's CRC checked.

    A frame whose CRC fails is never delivered. It counts as a ``crc_errors`` frame when the next header
    follows 16 bytes later (a frame damaged on the wire: it still took its place in the stream);
    otherwise the parser was not on a frame boundary and moves on by one byte (``garbage_bytes``)
    until it finds a header whose frame checks. Every frame the sensor sent takes one slot
    (``slots``): a good frame's slot is its place in the stream, so a damaged frame leaves a gap.

    Attributes:
        frames: good frames parsed.
        crc_errors: frames dropped for their CRC.
        garbage_bytes: bytes skipped outside frames (a Modbus answer before the stream, line noise).
        slots: frames seen, good or damaged.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.frames = 0
        self.crc_errors = 0
        self.garbage_bytes = 0
        self.slots = 0

    def reset(self) -> None:
        """Forget the bytes not yet parsed (a new stream)."""
        self._buffer.clear()

    def feed(self, data: bytes) -> tuple[list[tuple[int, ...]], list[int]]:
        """The good frames completed by ``data``: their six counts each (Fx..Mz), and each one's slot."""
        buffer = self._buffer
        buffer += data
        values: list[tuple[int, ...]] = []
        slots: list[int] = []
        i = 0
        n = len(buffer)
        while True:
            start = buffer.find(HEADER, i)
            if start < 0:
                keep = n - 1 if n > i and buffer[-1] == HEADER[0] else n  # a header's first byte may end it
                self.garbage_bytes += keep - i
                i = keep
                break
            self.garbage_bytes += start - i
            i = start
            if n - i < FRAME_SIZE:
                break
            frame = memoryview(buffer)[i : i + FRAME_SIZE]
            if crc16(frame[:14]) == int.from_bytes(frame[14:], "little"):
                values.append(_VALUES.unpack_from(frame, 2))
                slots.append(self.slots)
                self.slots += 1
                self.frames += 1
                i += FRAME_SIZE
            elif n - i < FRAME_SIZE + 2:  # wait for the next frame's header to judge this one
                frame.release()
                break
            elif buffer[i + FRAME_SIZE : i + FRAME_SIZE + 2] == HEADER:
                self.crc_errors += 1
                self.slots += 1
                i += FRAME_SIZE
            else:
                self.garbage_bytes += 1
                i += 1
            frame.release()
        del buffer[:i]
        return values, slots
