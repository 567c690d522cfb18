"""hapticlab's framed serial protocol at the byte level (``plugins/haptics/framing.py``): the CRC, the decoder's
resynchronisation after broken frames and garbage, and the specification's examples (docs/serial-protocol.md).
No port: bytes in, frames out."""

from __future__ import annotations

import numpy as np
from helpers import ROOT

from hapticlab.plugins.haptics import framing


def test_crc_is_ccitt_false_with_its_check_value():
    assert framing.crc16_ccitt_false(b"123456789") == 0x29B1  # the catalogue's check value for CRC-16/CCITT-FALSE
    assert framing.crc16_ccitt_false(b"") == 0xFFFF
    frame = framing.encode_frame(framing.HEARTBEAT, 7)
    crc = framing.crc16_ccitt_false(b"\x03\x07\x00")
    assert frame == bytes([0xA5, 0x5A, 0x03, 0x07, 0x00, crc & 0xFF, crc >> 8])


def test_every_single_bit_flip_is_rejected_and_the_next_frame_still_found():
    good = framing.encode_frame(framing.FORCE, 9, framing.pack_force(np.array([0.5, -1.0, 2.0])))
    after = framing.encode_frame(framing.HEARTBEAT, 10)
    for bit in range(16, 8 * len(good)):  # every bit after the sync pair
        broken = bytearray(good)
        broken[bit // 8] ^= 1 << (bit % 8)
        decoder = framing.FrameDecoder()
        frames = decoder.feed(bytes(broken) + after + b"\x00" * 80)  # padding completes a lengthened candidate
        assert [(f.kind, f.seq) for f in frames] == [(framing.HEARTBEAT, 10)], bit
        assert decoder.crc_errors + decoder.garbage_bytes > 0


def test_the_decoder_resynchronises_after_garbage_in_any_chunking():
    rng = np.random.default_rng(3)
    frames = [
        framing.encode_frame(framing.STATE, k, framing.State(k, rng.normal(size=3), rng.normal(size=3), k, 0).pack())
        for k in range(20)
    ]
    stream = bytearray()
    for frame in frames:  # garbage between frames, sync bytes and fake headers included
        stream += (
            bytes(rng.integers(0, 256, rng.integers(0, 12)).astype(np.uint8))
            + b"\xa5\x5a\x82\x05\x40"[: rng.integers(0, 6)]
            + frame
        )
    decoder, decoded = framing.FrameDecoder(), []
    cuts = sorted(rng.choice(len(stream), 60, replace=False))
    for a, b in zip([0, *cuts], [*cuts, len(stream)]):
        decoded += decoder.feed(bytes(stream[a:b]))
    assert [f.seq for f in decoded] == list(range(20))
    assert decoder.garbage_bytes > 0


def test_the_specifications_examples_are_the_encoders_bytes():
    spec = (ROOT / "docs" / "serial-protocol.md").read_text()
    heartbeat = framing.encode_frame(framing.HEARTBEAT, 7)
    force = framing.encode_frame(framing.FORCE, 9, framing.pack_force(np.array([0.5, -1.0, 2.0])))
    for frame in (heartbeat, force):
        assert "    " + frame.hex(" ").upper() + "\n" in spec
