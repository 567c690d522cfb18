"""The Bota Systems serial (BFT-*-SER, "gen0") wire: frames, CRC, status word, commands and the decoder.

Shared by the ``bota`` sensor (``bota.py``) and its emulator (``bota_emulator.py``). What is
known, and from where (docs/devices.md has the table):

* **The port**: 460 800 baud, 8N1 (Bota's Python example and bota-driver's default).
* **Frames** in run mode, little-endian, 37 bytes (:data:`FRAME`): header ``0xAA``, then 34
  data bytes: ``uint16 status``, ``float32 Fx Fy Fz Tx Ty Tz`` (N, N·m), ``uint32 timestamp``
  (µs, the sensor's clock), ``float32 temperature`` (°C); then ``uint16 crc`` over the 34 data
  bytes (not the header): CRC-16/X.25 (reflected polynomial 0x8408, init 0xFFFF, final
  XOR 0xFFFF), as Bota's C++ example computes it in ``crc16_x25`` (:func:`crc_x25`).
* **Status bits** (Bota's ``DataStatus``): bit 0 the application took too long, bit 1
  overrange, bit 2 invalid measurements, bit 3 raw measurements (calibration off); 4–15 reserved.
* **Commands** (ASCII, no terminator in Bota's example): ``C`` configuration mode, answered
  ``r,0,C,0``; ``c,T,K,D,B`` communication setup (temperature compensation 0/1, calibration
  0/1, data format 0 binary / 1 CSV, baud index 0–4: 9600, 57600, 115200, 230400, 460800),
  answered ``r,0,c,0``; ``f,S,C,F,D`` filter setup (sinc length, chop, fast, FIR disable),
  answered ``r,0,f,0``; ``R`` run, answered ``r,0,R,0``. The sample period is
  ``sinc_length / 51 200`` s (:func:`rate_of`). After power-on the sensor writes ``App Init``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

BAUDRATE = 460_800
"""The serial sensors' baud rate, bit/s."""
HEADER = 0xAA
"""The first byte of every frame."""
DATA = struct.Struct("<H6fIf")
"""A frame's data: status, Fx Fy Fz (N), Tx Ty Tz (N·m), timestamp (µs), temperature (°C)."""
FRAME_SIZE = 1 + DATA.size + 2
"""Header, data, CRC: 37 bytes."""
FRAME_DTYPE = np.dtype(
    [
        ("header", "u1"),
        ("status", "<u2"),
        ("wrench", "<f4", (6,)),
        ("timestamp_us", "<u4"),
        ("temperature_C", "<f4"),
        ("crc", "<u2"),
    ]
)
"""One frame as on the wire (packed, 37 bytes)."""
SINC_CLOCK_HZ = 51_200.0
"""The sample period is ``sinc_length / SINC_CLOCK_HZ`` s (Bota's example: 1.953125e-5 s per sinc tap)."""
SINC_LENGTHS = (51, 512)
"""Smallest and largest sinc length this side accepts (51: 1004 Hz; 512: 100 Hz)."""
BAUD_INDEX = {9600: 0, 57600: 1, 115200: 2, 230400: 3, 460800: 4}
"""The ``c`` command's baud index of each baud rate."""

STATUS_TOOK_TOO_LONG = 1 << 0
STATUS_OVERRANGE = 1 << 1
STATUS_INVALID = 1 << 2
STATUS_RAW = 1 << 3
STATUS_BITS = {
    0: "the sensor's application took too long",
    1: "overrange",
    2: "invalid measurements",
    3: "raw measurements (calibration off)",
}
"""What each bit of the status word says (bits 4–15 are reserved)."""

APP_INIT = b"App Init"
"""What the sensor writes when it (re)starts."""


def rate_of(sinc_length: int) -> float:
    """The sample rate of a sinc length, Hz (64 → 800 Hz, 512 → 100 Hz)."""
    return SINC_CLOCK_HZ / sinc_length


def reply(command: str, error: int = 0) -> bytes:
    """The sensor's answer to a command letter (``r,0,C,0``: 0 = accepted)."""
    return f"r,{error},{command},0".encode("ascii")


def communication_command(temperature_compensation: bool, calibration: bool = True, baudrate: int = BAUDRATE) -> bytes:
    """``c,T,K,D,B``: binary frames (D = 0), at ``baudrate``."""
    return f"c,{int(temperature_compensation)},{int(calibration)},0,{BAUD_INDEX[baudrate]}".encode("ascii")


def filter_command(sinc_length: int, chop: bool = False, fast: bool = False, fir_disable: bool = True) -> bytes:
    """``f,S,C,F,D``: the sinc length (the rate) and the filter switches (Bota's example's defaults)."""
    return f"f,{sinc_length},{int(chop)},{int(fast)},{int(fir_disable)}".encode("ascii")


# ---------------------------------------------------------------------------- CRC-16/X.25

_TABLE = []
for _byte in range(256):
    _crc = _byte
    for _ in range(8):
        _crc = (_crc >> 1) ^ 0x8408 if _crc & 1 else _crc >> 1
    _TABLE.append(_crc)
CRC_TABLE = tuple(_TABLE)
"""CRC-16/X.25 by byte (reflected polynomial 0x8408)."""
_CRC_ARRAY = np.array(CRC_TABLE, dtype=np.uint16)


def crc_x25(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/X.25 of ``data`` (init 0xFFFF, reflected, final XOR 0xFFFF; ``b"123456789"`` → 0x906E)."""
    crc = 0xFFFF
    table = CRC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc ^ 0xFFFF


def crc_x25_rows(data: np.ndarray) -> np.ndarray:
    """:func:`crc_x25` of each row of an (n, m) uint8 array: (n,) uint16, one numpy step per column."""
    crc = np.full(len(data), 0xFFFF, dtype=np.uint16)
    for column in data.T:
        crc = (crc >> 8) ^ _CRC_ARRAY[(crc ^ column) & 0xFF]
    return crc ^ 0xFFFF


def encode_frames(status, force_S, torque_S, timestamp_us, temperature_C) -> bytes:
    """Frames of n readings (arrays of n, or (n, 3)): float32 values, the CRC over each frame's data."""
    n = len(status)
    frames = np.zeros(n, dtype=FRAME_DTYPE)
    frames["header"] = HEADER
    frames["status"] = status
    frames["wrench"] = np.concatenate([np.reshape(force_S, (n, 3)), np.reshape(torque_S, (n, 3))], axis=1)
    frames["timestamp_us"] = np.asarray(timestamp_us, dtype=np.int64) % 2**32
    frames["temperature_C"] = temperature_C
    raw = frames.view(np.uint8).reshape(n, FRAME_SIZE)
    frames["crc"] = crc_x25_rows(raw[:, 1 : 1 + DATA.size])
    return frames.tobytes()


# ---------------------------------------------------------------------------- decoding


@dataclass
class DecoderCounts:
    """What the decoder saw since it started: frames kept, frames whose CRC failed, bytes skipped while
    looking for a header (text replies, line noise, the tail of a broken frame)."""

    frames: int = 0
    crc_errors: int = 0
    skipped_bytes: int = 0
    text: bytearray = field(default_factory=bytearray)


class FrameDecoder:
    """Frames out of a byte stream, resynchronised on the header after a bad CRC.

    A frame is kept when it starts with ``0xAA`` and its CRC matches. At a header whose CRC fails
    (a corrupted frame, or a ``0xAA`` inside the data of a frame the stream entered in its middle)
    the decoder counts a CRC error and looks for the next header one byte further on, so a broken
    frame costs itself and nothing after it. ``feed`` returns the kept frames as one structured
    array (:data:`FRAME_DTYPE`); bytes that are no frame are counted as skipped, and the last
    ``keep_text`` of them are kept in ``counts.text`` (the answers to commands are text).
    """

    def __init__(self, keep_text: int = 256):
        self.counts = DecoderCounts()
        self.keep_text = keep_text
        self._buffer = bytearray()

    def reset(self) -> None:
        """Forget the bytes held (a partial frame) and the text seen."""
        self._buffer.clear()
        self.counts.text.clear()

    def feed(self, data: bytes) -> np.ndarray:
        """The frames completed by ``data`` (in order)."""
        buf = self._buffer
        buf += data
        kept: list[bytes] = []
        pos, end = 0, len(buf)
        while end - pos >= FRAME_SIZE:
            if buf[pos] != HEADER:
                nxt = buf.find(HEADER, pos + 1)
                stop = end if nxt < 0 else nxt
                self._skip(buf, pos, stop)
                pos = stop
                continue
            frame = bytes(buf[pos : pos + FRAME_SIZE])
            if crc_x25(frame[1:-2]) == frame[-2] | (frame[-1] << 8):
                kept.append(frame)
                pos += FRAME_SIZE
            else:
                self.counts.crc_errors += 1
                self._skip(buf, pos, pos + 1)
                pos += 1
        del buf[:pos]
        self.counts.frames += len(kept)
        if not kept:
            return np.zeros(0, dtype=FRAME_DTYPE)
        return np.frombuffer(b"".join(kept), dtype=FRAME_DTYPE).copy()

    def _skip(self, buf: bytearray, start: int, stop: int) -> None:
        self.counts.skipped_bytes += stop - start
        text = self.counts.text
        text += buf[start:stop]
        if len(text) > self.keep_text:
            del text[: len(text) - self.keep_text]


def describe_status(word: int) -> str:
    """The status word in words ("healthy" when 0)."""
    if word == 0:
        return "healthy"
    names = [name for bit, name in STATUS_BITS.items() if word & (1 << bit)]
    if word & ~0xF:
        names.append(f"reserved bits 0x{word & ~0xF:04x}")
    return ", ".join(names)
