"""The host side of hapticlab's framed protocol (``framing.py``) over a serial port: handshake, exchanges, pipelining.

The byte level is ``framing.py`` (shared with the emulator); this module is the conversation:
HELLO until the device answers, one FORCE → STATE exchange per command, and, for a loop that must
not wait on the wire, FORCEs posted now and their STATEs collected when they have come.
"""

from __future__ import annotations

import math
import time

import numpy as np

from hapticlab.plugins.haptics import framing
from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError
from hapticlab.plugins.haptics.serial_port import Reading, SerialPort


def _finite(state: framing.State) -> bool:
    """Every number in a STATE is finite (a device's NaN is a bad reply, never a position)."""
    return all(map(math.isfinite, state.p_DoHo_D)) and all(map(math.isfinite, state.v_DHo_D))


class HapticlabLink:
    """Our framed protocol (``framing.py``): HELLO handshake, FORCE → STATE exchanges, CRC-checked."""

    def __init__(self, port: SerialPort, read_timeout: float, watchdog_s: float):
        self.port, self.read_timeout, self.watchdog_s = port, read_timeout, watchdog_s
        self.decoder = framing.FrameDecoder()
        self.seq = 0
        self.max_force: float | None = None
        self.counters = {"crc_errors": 0, "garbage_bytes": 0, "naks": 0, "stale_replies": 0, "bad_replies": 0}
        self.outstanding: dict[int, float] = {}  # pipelined: seq → when it was sent (monotonic s), oldest first

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFF
        return self.seq

    def _sync_counters(self) -> None:
        self.counters["crc_errors"] = self.decoder.crc_errors
        self.counters["garbage_bytes"] = self.decoder.garbage_bytes

    def handshake(self, timeout_s: float) -> str:
        where = f"haptic.port {self.port.name}"
        deadline = time.monotonic() + timeout_s
        self.port.discard_input()  # a board reset on open prints its boot banner
        received = 0
        while time.monotonic() < deadline:
            seq = self._next_seq()
            self.port.write(framing.encode_frame(framing.HELLO, seq, framing.pack_hello(self.watchdog_s)))
            retry_at = min(deadline, time.monotonic() + 0.1)  # an Arduino may still be in its bootloader
            while time.monotonic() < retry_at:
                data = self.port.read(4096, retry_at)
                received += len(data)
                for frame in self.decoder.feed(data):
                    if (
                        frame.kind == framing.NAK
                        and len(frame.payload) == framing.NAK_FORMAT.size
                        and frame.payload[1] == framing.NAK_VERSION
                    ):  # other NAKs: line noise, try again
                        raise MasterOpenError(
                            f"{where}: the device refused HELLO: it does not speak hapticlab "
                            f"protocol version {framing.PROTOCOL_VERSION}"
                        )
                    if frame.kind == framing.HELLO_ACK and len(frame.payload) == framing.HELLO_ACK_FORMAT.size:
                        ack = framing.HelloAck.unpack(frame.payload)
                        if ack.version != framing.PROTOCOL_VERSION:
                            raise MasterOpenError(
                                f"{where}: the device speaks hapticlab protocol version "
                                f"{ack.version}, this host speaks {framing.PROTOCOL_VERSION}"
                            )
                        if not (math.isfinite(ack.max_force) and ack.max_force > 0):
                            raise MasterOpenError(f"{where}: the device reports a maximum force of {ack.max_force!r} N")
                        self.max_force = ack.max_force
                        self._sync_counters()
                        return (
                            f"hapticlab protocol v{ack.version} device {ack.device_id} firmware "
                            f"{ack.firmware_version}, max {ack.max_force:g} N, {ack.max_rate_hz:g} Hz"
                        )
        self._sync_counters()
        if received:
            raise MasterOpenError(
                f"{where}: {received} byte(s) arrived in {timeout_s:g} s but no hapticlab "
                f"HELLO_ACK ({self.decoder.crc_errors} CRC error(s)): wrong baud rate, "
                'or not a hapticlab master (protocol = "inverse3"?)'
            )
        raise MasterOpenError(
            f"{where}: no reply to the hapticlab HELLO within {timeout_s:g} s "
            "(is the firmware flashed, the baud rate right, the device powered?)"
        )

    def exchange(self, force_D: np.ndarray) -> Reading | None:
        seq = self._next_seq()
        self.outstanding.clear()  # a waited-for exchange supersedes what a pipeline had in flight
        self.port.write(framing.encode_frame(framing.FORCE, seq, framing.pack_force(force_D)))
        return self._await_state(seq)

    # pipelined: write now, collect the replies that have come when next asked --------------------

    def post(self, force_D: np.ndarray) -> None:
        """Write one FORCE without waiting for its STATE."""
        seq = self._next_seq()
        self.outstanding.pop(seq, None)  # a seq 256 commands old is long answered or long lost
        self.outstanding[seq] = time.monotonic()
        self.port.write(framing.encode_frame(framing.FORCE, seq, framing.pack_force(force_D)))

    def poll(self) -> list[Reading | None]:
        """The replies that have arrived, in order, without blocking: a Reading, or None for a bad reply.

        A STATE answers its command and every older one still outstanding; a
        broken frame (CRC) or a NAK stands for the oldest outstanding command.
        Raises MasterLostError when the oldest outstanding command has waited
        longer than the read timeout.
        """
        waiting = self.port.waiting()
        if not waiting and not self.outstanding:
            return []
        errors_before = self.decoder.crc_errors
        frames = self.decoder.feed(self.port.read(waiting, 0.0)) if waiting else []
        outcomes: list[Reading | None] = []
        for _ in range(self.decoder.crc_errors - errors_before):
            outcomes.append(None)
            self._forget_oldest()
        for frame in frames:
            if frame.kind == framing.STATE and len(frame.payload) == framing.STATE_FORMAT.size:
                state = framing.State.unpack(frame.payload)
                if state.ack_seq not in self.outstanding:
                    self.counters["stale_replies"] += 1
                    continue
                while self.outstanding:  # answered, and so are the older ones (their replies are late or lost)
                    seq = next(iter(self.outstanding))
                    del self.outstanding[seq]
                    if seq == state.ack_seq:
                        break
                if _finite(state):
                    outcomes.append(Reading(state.p_DoHo_D, state.v_DHo_D, state.buttons, state.status))
                else:
                    self.counters["bad_replies"] += 1
                    outcomes.append(None)
            elif frame.kind == framing.NAK and len(frame.payload) == framing.NAK_FORMAT.size:
                self.counters["naks"] += 1
                if frame.payload[1] == framing.NAK_NOT_READY:
                    raise MasterLostError(
                        f"{self.port.name}: the device forgot the handshake (restarted?)", "restarted"
                    )
                self.outstanding.pop(frame.payload[0], None) if frame.payload[
                    0
                ] in self.outstanding else self._forget_oldest()
                outcomes.append(None)
            else:
                self.counters["bad_replies"] += 1
        self._sync_counters()
        if self.outstanding:
            waited = time.monotonic() - next(iter(self.outstanding.values()))
            if waited > self.read_timeout:
                self.outstanding.clear()
                raise MasterLostError(f"{self.port.name}: no reply within {self.read_timeout * 1e3:g} ms")
        return outcomes

    def _forget_oldest(self) -> None:
        if self.outstanding:
            del self.outstanding[next(iter(self.outstanding))]

    def _await_state(self, seq: int) -> Reading | None:
        deadline = time.monotonic() + self.read_timeout
        errors_before = self.decoder.crc_errors
        arrived = False
        while True:
            data = self.port.read(4096, deadline)
            arrived |= bool(data)
            for frame in self.decoder.feed(data):
                if frame.kind == framing.STATE and len(frame.payload) == framing.STATE_FORMAT.size:
                    state = framing.State.unpack(frame.payload)
                    if state.ack_seq != seq:
                        self.counters["stale_replies"] += 1
                        continue
                    self._sync_counters()
                    if not _finite(state):
                        self.counters["bad_replies"] += 1
                        return None
                    return Reading(state.p_DoHo_D, state.v_DHo_D, state.buttons, state.status)
                if frame.kind == framing.NAK and len(frame.payload) == framing.NAK_FORMAT.size:
                    self.counters["naks"] += 1
                    self._sync_counters()
                    if frame.payload[1] == framing.NAK_NOT_READY:
                        raise MasterLostError(
                            f"{self.port.name}: the device forgot the handshake (restarted?)", "restarted"
                        )
                    return None
                self.counters["bad_replies"] += 1  # a frame that answers nothing we asked
            self._sync_counters()
            if self.decoder.crc_errors > errors_before and not self.decoder.pending() and not self.port.waiting():
                return None  # the reply came and was broken: no need to wait out the timeout
            if time.monotonic() >= deadline:
                if arrived:
                    self.counters["bad_replies"] += 1
                    return None
                raise MasterLostError(f"{self.port.name}: no reply within {self.read_timeout * 1e3:g} ms")
