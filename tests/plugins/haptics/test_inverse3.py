"""The Inverse3 protocol: Haply's own client (``HaplyHardwareAPI``) against our emulator, and our plugin against both.

Haply's client is the reference for the bytes: if its wake-up and its
force/state exchange work against the emulator, and our plugin writes the same
bytes as Haply's client for the same force, the emulator and the plugin speak
the device's protocol, not one of our own making.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

import numpy as np
import pytest

from hapticlab.core.types import HapticCommand
from hapticlab.plugins.haptics import inverse3
from hapticlab.plugins.haptics.master import MasterLostError
from hapticlab.plugins.haptics.serial import SerialHaptic

HaplyHardwareAPI = pytest.importorskip("HaplyHardwareAPI")


def command(force, enabled=True, t_ns=0):
    return HapticCommand(t_ns, np.asarray(force, dtype=float), enabled, "" if enabled else "test")


def test_the_layout_in_bytes():
    # as HaplyHardwareAPI 0.1.13 writes end_effector_force([1.5, -2.25, 3.0])
    assert inverse3.pack_force_request(np.array([1.5, -2.25, 3.0])).hex() == "2a0000c03f000010c000004040"
    assert (inverse3.DEVICE_INFO_SIZE, inverse3.FORCE_REQUEST_SIZE, inverse3.STATE_SIZE) == (22, 13, 25)
    with pytest.raises(ValueError, match="expected a 25-byte end-effector state starting 0x2B, got 3 byte"):
        inverse3.unpack_state(b"\x2b\x00\x00")


def test_haplys_client_wakes_the_emulator_and_exchanges_force_for_state(master_emulator):
    with master_emulator("inverse3", device_id=0x1234) as em:
        stream = HaplyHardwareAPI.SerialStream(em.port)  # held: Inverse3 keeps only a pointer to it
        device = HaplyHardwareAPI.Inverse3(stream, 2.0)
        info = device.device_wakeup_dict()
        assert info["device_id"] == 0x1234 and info["device_model_number"] == 3
        assert str(info["device_id_ext"]) == str(em.uuid)
        rng = np.random.default_rng(5)
        for _ in range(20):
            force = rng.uniform(-3, 3, 3)
            position, velocity = device.end_effector_force(force.tolist())
            np.testing.assert_array_equal(em.forces[-1], force.astype(np.float32))
            p32, v32 = em.last_reply
            assert position == p32.tolist() and velocity == v32.tolist()  # float32 → double, exactly
        assert em.counts.forces == 20 and em.counts.unknown_bytes == 0
        del device, stream


def test_our_plugin_writes_the_bytes_haplys_client_writes(pty_pair):
    """Both hosts on a bare pty, one after the other: the wake-up and the force request, byte for byte."""
    master, slave = pty_pair
    tty.setraw(slave)
    port = os.ttyname(slave)
    info = inverse3.DeviceInfo(7, 3, 1, 2, __import__("uuid").UUID(int=99))
    state = inverse3.pack_state(np.array([0.01, -0.02, 0.15]), np.array([0.1, 0.0, -0.1]))
    force = [1.5, -2.25, 3.0]

    def device(replies: list[bytes], requests: list[bytes]):
        for reply in replies:
            select.select([master], [], [], 5.0)
            requests.append(os.read(master, 64))
            os.write(master, reply)

    heard_haply: list[bytes] = []
    thread = threading.Thread(target=device, args=([info.pack(), state], heard_haply), daemon=True)
    thread.start()
    stream = HaplyHardwareAPI.SerialStream(port)
    client = HaplyHardwareAPI.Inverse3(stream, 2.0)
    client.device_wakeup_dict()
    client.end_effector_force(force)
    thread.join(5.0)
    del client, stream

    heard_ours: list[bytes] = []
    thread = threading.Thread(target=device, args=([info.pack(), state], heard_ours), daemon=True)
    thread.start()
    plugin = SerialHaptic(port, "inverse3", device_max_force=5.0, read_timeout=1.0)
    plugin.open()
    plugin.send(command(force))
    thread.join(5.0)
    assert heard_ours == heard_haply == [b"\x0a", inverse3.pack_force_request(np.array(force))]
    np.testing.assert_array_equal(plugin.state().p_DoHo_D, np.float32([0.01, -0.02, 0.15]).astype(float))
    assert "Haply Inverse3 device 7 (00000000-0000-0000-0000-000000000063)" in plugin.info
    plugin.port.close()


@pytest.fixture
def emulator(master_emulator):
    with master_emulator("inverse3") as em:
        yield em


@pytest.fixture
def device(emulator):
    dev = SerialHaptic(emulator.port, "inverse3", device_max_force=4.0, read_timeout=1.0, reconnect_interval=0.05)
    dev.open()
    yield dev
    dev.close()


def test_plugin_round_trip_is_bit_exact_and_clamped(emulator, device):
    rng = np.random.default_rng(2)
    for k in range(100):
        force = rng.uniform(-2, 2, 3)
        device.send(command(force, t_ns=k))
        np.testing.assert_array_equal(emulator.forces[-1], force.astype(np.float32))
        np.testing.assert_array_equal(device.state().p_DoHo_D, emulator.last_reply[0].astype(float))
        np.testing.assert_array_equal(device.state().v_DHo_D, emulator.last_reply[1].astype(float))
    for force in ([100.0, 0, 0], [np.nan, 1, 1], [1e300, 1e300, -1e300]):
        device.send(command(force))
    received = np.array(list(emulator.forces)[-3:], dtype=float)
    assert np.isfinite(received).all() and np.linalg.norm(received, axis=1).max() <= 4.0
    assert not received[1].any()


def test_a_bad_reply_is_counted_and_the_next_exchange_is_clean(emulator, device):
    device.send(command([0.1, 0.0, 0.0]))
    before = device.state()
    emulator.corrupt_replies(2)
    device.send(command([0.2, 0.0, 0.0]))
    device.send(command([0.3, 0.0, 0.0]))
    assert device.state() is before and device.health_counters()["bad_replies"] == 2
    device.send(command([0.4, 0.0, 0.0]))
    np.testing.assert_array_equal(device.state().p_DoHo_D, emulator.last_reply[0].astype(float))
    assert emulator.forces[-1].tolist() == pytest.approx([0.4, 0.0, 0.0])


def test_an_unplugged_or_silent_inverse3_raises(emulator, device):
    device.send(command([0.1, 0.0, 0.0]))
    device.link.read_timeout = 0.2  # from here on the timeout is what is tested: make it short
    emulator.stop_answering()
    with pytest.raises(MasterLostError, match="no reply within 200 ms"):
        device.send(command([0.1, 0.0, 0.0]))
    emulator.unplug()
    with pytest.raises(MasterLostError, match="lost"):
        device.send(command([0.1, 0.0, 0.0]))
    assert device.health_counters()["losses"] == 1


def test_bad_replies_beyond_the_limit_zero_the_force_and_a_retry_finds_the_device(emulator, device):
    device.send(command([1.0, 0.0, 0.0]))
    emulator.corrupt_replies(6)
    for _ in range(5):
        device.send(command([1.0, 0.0, 0.0]))
    with pytest.raises(MasterLostError, match="6 bad replies in a row"):
        device.send(command([1.0, 0.0, 0.0]))
    deadline = time.monotonic() + 10.0
    while emulator.forces[-1].any() and time.monotonic() < deadline:
        time.sleep(0.002)
    assert not emulator.forces[-1].any()  # zero written at once: an Inverse3 holds its last force
    while time.monotonic() < deadline:  # the retry reads past the zero's reply, then its own
        try:
            device.send(command([1.0, 0.0, 0.0]))
            break
        except MasterLostError:
            time.sleep(0.005)
    device.send(command([0.25, 0.0, 0.0]))
    assert emulator.forces[-1].tolist() == [0.25, 0.0, 0.0]
    np.testing.assert_array_equal(device.state().p_DoHo_D, emulator.last_reply[0].astype(float))
