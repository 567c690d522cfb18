"""The serial link to a Robotiq FT 300: open the port, stop a stream left running, read the registers
with ``minimalmodbus``, start the stream, and read its bytes.

Every OS-level or Modbus failure becomes a :class:`FT300LinkError` naming the port and what went wrong,
so the sensor plugin reports it in one line.
"""

from __future__ import annotations

import contextlib
import time
import typing

from hapticlab.plugins.sensors import robotiq_protocol as rq

if typing.TYPE_CHECKING:
    import serial as pyserial

QUIET_S = 0.08
"""No byte for this long after the stop bytes: the stream has stopped (Robotiq's driver: 80 ms), s."""
SETTLE_S = 0.1
"""A sensor that was streaming is given this long to return to Modbus (Robotiq's driver waits 100 ms), s."""


class FT300LinkError(ConnectionError):
    """The port or the sensor failed: the message names the port and what went wrong."""


class FT300Link:
    """One open connection to the sensor, streaming once :meth:`open` returns.

    Args:
        port: the serial device.
        slave_id: the sensor's Modbus slave id.
        baudrate: bit/s.
        open_timeout: how long :meth:`open` may wait for the stream to stop, each answer and the first
            frame, s.

    Attributes:
        info: ``firmware``, ``serial_number``, ``production_year`` as the sensor reports them (after open).
        streamed_before: the sensor was streaming when the port opened (a session that ended without stopping it).
    """

    def __init__(self, port: str, slave_id: int = rq.SLAVE_ID, baudrate: int = rq.BAUDRATE, open_timeout: float = 1.0):
        self.port, self.slave_id, self.baudrate, self.open_timeout = port, slave_id, baudrate, open_timeout
        self.info: dict[str, str] = {}
        self.streamed_before = False
        self._serial: pyserial.Serial | None = None

    def _fail(self, what: str, exc: BaseException | None = None) -> FT300LinkError:
        why = "" if exc is None else f": {getattr(exc, 'strerror', None) or exc or type(exc).__name__}"
        return FT300LinkError(f"Robotiq FT 300 on {self.port}: {what}{why}")

    def open(self) -> bytes:
        """Open the port, stop any stream, read the sensor's registers, start the stream; the bytes read while
        waiting for its first frame (they hold it). Raises FT300LinkError."""
        import minimalmodbus
        import serial

        try:
            self._serial = ser = serial.Serial(
                self.port,
                self.baudrate,
                bytesize=8,
                parity="N",
                stopbits=1,
                timeout=0,
                write_timeout=0.5,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise self._fail("cannot open the port", exc) from None
        try:
            self._stop_stream(ser)
            ser.timeout = min(0.2, self.open_timeout)
            modbus = minimalmodbus.Instrument(ser, self.slave_id)
            modbus.clear_buffers_before_each_transaction = True
            try:
                self.info = {
                    "firmware": rq.firmware_version(modbus.read_registers(rq.REG_FIRMWARE, 3)),
                    "serial_number": rq.serial_number(modbus.read_registers(rq.REG_SERIAL, 4)),
                    "production_year": str(modbus.read_register(rq.REG_YEAR)),
                }
            except (minimalmodbus.ModbusException, OSError, ValueError) as exc:
                raise self._fail(
                    f"no Modbus answer from slave {self.slave_id} at {self.baudrate} bit/s 8N1 "
                    "(is it an FT 300, powered, on this port?)",
                    exc,
                ) from None
            with contextlib.suppress(minimalmodbus.ModbusException):
                # the echo may be missing or mixed with the first frames: the frames themselves say it started
                modbus.write_register(rq.REG_STREAM, rq.STREAM_START, functioncode=16)
            ser.timeout = 0
            return self._first_bytes(ser)
        except BaseException:
            self.close(stop=False)
            raise

    def _stop_stream(self, ser: pyserial.Serial) -> None:
        """Send the stop bytes and wait until the port is quiet; then empty it."""
        ser.write(bytes([rq.STOP_BYTE]) * rq.STOP_COUNT)
        deadline = time.monotonic() + self.open_timeout
        quiet_since = time.monotonic()
        while time.monotonic() - quiet_since < QUIET_S:
            if time.monotonic() > deadline:
                raise self._fail(f"the sensor still streams {self.open_timeout:g} s after {rq.STOP_COUNT} stop bytes")
            waiting = ser.in_waiting
            if waiting:
                ser.read(waiting)
                self.streamed_before = True
                quiet_since = time.monotonic()
            time.sleep(0.005)
        if self.streamed_before:
            time.sleep(SETTLE_S)
        ser.reset_input_buffer()

    def _first_bytes(self, ser: pyserial.Serial) -> bytes:
        """Read until a whole frame's header and bytes could be there (the caller parses them)."""
        deadline = time.monotonic() + self.open_timeout
        data = b""
        while time.monotonic() < deadline:
            data += self.read()
            at = data.find(rq.HEADER)
            if at >= 0 and len(data) - at >= 2 * rq.FRAME_SIZE:  # a frame and the next one's header
                return data
            time.sleep(0.002)
        if rq.HEADER in data:
            return data
        raise self._fail(
            f"the stream did not start within {self.open_timeout:g} s of writing 0x0200 to register {rq.REG_STREAM} "
            f"({len(data)} byte(s), no frame)"
        )

    def read(self) -> bytes:
        """The bytes received since the last read (b"" when none); raises FT300LinkError when the port fails."""
        ser = self._serial
        if ser is None:
            raise self._fail("not open")
        try:
            waiting = ser.in_waiting
            return ser.read(waiting) if waiting else b""
        except OSError as exc:  # serial.SerialException is an OSError
            raise self._fail("disconnected (the port's read failed)", exc) from None

    def write(self, data: bytes) -> None:
        """Write ``data`` (the start request sent again); raises FT300LinkError when the port fails."""
        if self._serial is None:
            raise self._fail("not open")
        try:
            self._serial.write(data)
        except OSError as exc:
            raise self._fail("disconnected (the port's write failed)", exc) from None

    def close(self, stop: bool = True) -> None:
        """Stop the stream (the stop bytes) and close the port; a port that already failed is only closed."""
        ser, self._serial = self._serial, None
        if ser is None:
            return
        with contextlib.suppress(OSError):
            if stop:
                ser.write(bytes([rq.STOP_BYTE]) * rq.STOP_COUNT)
                ser.flush()
        with contextlib.suppress(OSError):
            ser.close()


def start_request(slave_id: int = rq.SLAVE_ID) -> bytes:
    """The FC16 request writing ``STREAM_START`` to register 410, as bytes."""
    body = bytes((slave_id, rq.FC_WRITE_MANY)) + rq.REG_STREAM.to_bytes(2, "big") + (1).to_bytes(2, "big")
    return rq.with_crc(body + bytes((2,)) + rq.STREAM_START.to_bytes(2, "big"))
