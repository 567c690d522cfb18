"""The master emulator (``plugins/haptics/master_emulator.py``): a serial haptic master on a pseudo-terminal, driven
by the ``serial`` plugin or by hand; its force log, its NAKs, the hand on its handle (``handle_motion.py``), its
scheduled faults and its command line (``master_emulator_cli.py``).

The emulator and the plugin opened on it are tests/plugins/haptics/conftest.py's ``emulator`` and ``device``.
Checks compare bytes, counts and exceptions, never durations.
"""

from __future__ import annotations

import signal
import sys
import threading
import time

import numpy as np
import pytest
from helpers import GUARD_S, READ_TIMEOUT_S, haptic_command

from hapticlab.plugins.haptics import framing
from hapticlab.plugins.haptics.handle_motion import recorded_motion, scripted_motion
from hapticlab.plugins.haptics.serial import SerialHaptic


def test_the_emulator_logs_each_force_with_when_it_came_off_the_wire(emulator, device, tmp_path):
    rng = np.random.default_rng(2)
    sent = []
    for k in range(50):
        force = rng.uniform(-2.5, 2.5, 3)
        before = time.monotonic_ns()
        device.send(haptic_command(force, t_ns=k))  # waits for the reply: the frame was read before it returns
        sent.append((before, time.monotonic_ns(), force.astype(np.float32)))
    received = list(emulator.received_ns)
    assert len(received) == 50
    for (before, after, _), t in zip(sent, received):
        assert before <= t <= after  # the receipt time is on the clock the sender uses, between write and reply
    log = tmp_path / "forces.csv"
    assert emulator.write_forces(log) == 50
    rows = log.read_text().splitlines()
    assert rows[0] == "received_ns,fx,fy,fz" and len(rows) == 51
    for row, (_, _, force), t in zip(rows[1:], sent, received):
        cells = row.split(",")
        assert int(cells[0]) == t
        np.testing.assert_array_equal(np.array(cells[1:], dtype=float).astype(np.float32), force)
    with pytest.raises(FileExistsError):
        emulator.write_forces(log)  # never over an existing file


def test_the_device_naks_a_host_frame_with_a_bad_crc(emulator):
    import serial

    with serial.Serial(emulator.port, timeout=1.0) as port:
        hello = bytearray(framing.encode_frame(framing.HELLO, 1, framing.pack_hello(0.1)))
        hello[-1] ^= 0x40
        port.write(bytes(hello))
        frames = framing.FrameDecoder().feed(port.read(framing.HEADER_SIZE + framing.NAK_FORMAT.size + 2))
        assert [(f.kind, f.payload[1]) for f in frames] == [(framing.NAK, framing.NAK_CRC)]
        port.write(framing.encode_frame(framing.FORCE, 2, framing.pack_force(np.zeros(3))))  # before any HELLO
        frames = framing.FrameDecoder().feed(port.read(framing.HEADER_SIZE + framing.NAK_FORMAT.size + 2))
        assert [(f.kind, f.payload[0], f.payload[1]) for f in frames] == [(framing.NAK, 2, framing.NAK_NOT_READY)]
    assert emulator.counts.crc_errors == 1 and not emulator.forces


# --------------------------------------------------------------------------- the hand on the handle


def test_scripted_and_recorded_paths(tmp_path, master_emulator):
    p, v = scripted_motion("figure8", 0.02, 4.0, (0.0, 0.1, 0.2))(1.0)  # a quarter lap: the lobe's tip
    np.testing.assert_allclose(p, [0.02, 0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(v, [0.0, -0.02 * 2 * np.pi / 4.0, 0.0], atol=1e-12)
    path = tmp_path / "hand.csv"
    path.write_text("t,x,y,z\n0,0,0,0\n1,0.01,0,0\n2,0.01,0.02,0\n")
    motion = recorded_motion(path)
    p, v = motion(1.5)
    np.testing.assert_allclose(p, [0.01, 0.01, 0.0])
    np.testing.assert_allclose(v, [0.0, 0.02, 0.0])
    np.testing.assert_allclose(motion(2.25)[0], [0.0025, 0.0, 0.0])  # in a loop
    with master_emulator(motion=motion) as em:
        dev = SerialHaptic(em.port, read_timeout=READ_TIMEOUT_S)
        dev.open()
        dev.send(haptic_command([0.0, 0.0, 0.0]))
        assert 0.0 <= dev.state().p_DoHo_D[0] <= 0.01 and 0.0 <= dev.state().p_DoHo_D[1] <= 0.02
        dev.close()
    (tmp_path / "bad.csv").write_text("t,x,y\n0,0,0\n")
    with pytest.raises(ValueError, match=r"bad.csv: needs a header row with columns t, x, y, z"):
        recorded_motion(tmp_path / "bad.csv")


# --------------------------------------------------------------------------- scheduled faults and the command line


def test_scheduled_faults_parse_and_inject(emulator, device):
    from hapticlab.plugins.haptics.master_emulator_cli import ScheduledFault

    assert ScheduledFault.parse("crc@5:3") == ScheduledFault("crc", 5.0, 3.0)
    assert ScheduledFault.parse("unplug@12") == ScheduledFault("unplug", 12.0, None)
    with pytest.raises(ValueError, match="unknown kind 'melt'; known: crc, garbage, silent, restart, unplug"):
        ScheduledFault.parse("melt@1")
    with pytest.raises(ValueError, match="expected KIND@SECONDS"):
        ScheduledFault.parse("crc@soon")
    ScheduledFault("crc", 0.0, 2.0).inject(emulator, threading.Event())
    ScheduledFault("garbage", 0.0, 10.0).inject(emulator, threading.Event())
    for _ in range(3):
        device.send(haptic_command([0.1, 0.0, 0.0]))
    counters = device.health_counters()
    assert counters["crc_errors"] == 2 and counters["garbage_bytes"] >= 10 and device.errors_in_row == 0


EMULATE_MASTER = (
    "import argparse, sys; from hapticlab.plugins.haptics import master_emulator_cli as m; "
    "p = argparse.ArgumentParser(); m.add_arguments(p); sys.exit(m.run(p.parse_args(sys.argv[1:])))"
)


def test_the_command_line_emulator_prints_its_port_first_and_ends_on_sigterm(spawn_process):
    proc = spawn_process(
        [sys.executable, "-c", EMULATE_MASTER, "--path", "figure8", "--max-force", "2.5"], "emulate master"
    )
    port = proc.first_line().strip()
    assert port.startswith("/dev/pts/")
    assert proc.next_line().startswith(f"hapticlab master emulator on {port}: handle on figure8")
    dev = SerialHaptic(port, device_max_force=9.0, read_timeout=READ_TIMEOUT_S)
    dev.open()
    assert dev.max_force == 2.5
    dev.send(haptic_command([0.0, 1.0, 0.0]))
    dev.close()
    out = proc.finish(signal.SIGTERM, GUARD_S)
    assert proc.returncode == 0
    assert out.startswith("2 force command(s)")  # ours and the zero that close() writes


def test_a_sigterm_sent_as_soon_as_the_port_is_printed_ends_the_emulator_cleanly(spawn_process):
    for _ in range(5):  # the port is printed once the handler is in place: no window for the default handler
        proc = spawn_process([sys.executable, "-c", EMULATE_MASTER], "emulate master")
        assert proc.first_line().startswith("/dev/pts/")
        out = proc.finish(signal.SIGTERM, GUARD_S)
        assert proc.returncode == 0 and "0 force command(s)" in out
