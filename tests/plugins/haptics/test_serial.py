"""The ``serial`` haptic output over real pseudo-terminals, against the master emulator (hapticlab protocol).

Every test opens a pty pair through ``MasterEmulator``; the plugin opens the
slave side with pyserial as it would a USB serial port. Checks compare bytes
(float32 as on the wire), counts and exceptions, never durations: loops that
wait for the emulator end on a condition, with a deadline only as a guard. The emulator and the plugin
opened on it are conftest.py's ``emulator`` and ``device``; the byte level is test_framing.py, the emulator's
own features test_master_emulator.py.
"""

from __future__ import annotations

import os
import threading
import time
import tty

import numpy as np
import pytest
from helpers import GUARD_S, READ_TIMEOUT_S, haptic_command

from hapticlab.core.host.interfaces import EmitsEvents, HapticOutput, ReportsHealth
from hapticlab.core.host.registry import ConfigError, Registry, make_plugin_manager
from hapticlab.plugins.haptics import framing
from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError, clamp_force
from hapticlab.plugins.haptics.serial import SerialHaptic


def built(**options):
    """The serial plugin as a session builds it from ``[haptic]``: an option error names the full key."""
    return Registry(make_plugin_manager(load_entry_points=False)).create(
        "haptic_output", "serial", options, where="haptic"
    )


# --------------------------------------------------------------------------- round trip over a pty


def test_the_plugin_is_a_haptic_output_with_events_and_health(device):
    assert isinstance(device, HapticOutput) and isinstance(device, EmitsEvents) and isinstance(device, ReportsHealth)
    assert "serial" in Registry(make_plugin_manager(load_entry_points=False)).names("haptic_output")


def test_round_trip_forces_and_poses_are_bit_exact(emulator, device):
    assert device.info.startswith("hapticlab protocol v1 device 19521") and device.max_force == 5.0
    rng = np.random.default_rng(1)
    for k in range(300):
        force = rng.uniform(-2.5, 2.5, 3)
        device.send(haptic_command(force, t_ns=k))
        np.testing.assert_array_equal(emulator.forces[-1], force.astype(np.float32))  # the wire's float32
        state = device.state()
        p32, v32 = emulator.last_reply
        assert state.t_ns == k
        np.testing.assert_array_equal(state.p_DoHo_D, p32.astype(np.float64))
        np.testing.assert_array_equal(state.v_DHo_D, v32.astype(np.float64))
        np.testing.assert_array_equal(state.quat_DH, [1.0, 0.0, 0.0, 0.0])
    assert len(emulator.forces) == 300 and emulator.counts.crc_errors == 0
    assert device.health_counters()["crc_errors"] == 0 and device.health_counters()["written"] == 300
    # the handle moved along the emulator's circle (radius 0.03 m about the origin, in the x-y plane)
    assert abs(np.linalg.norm(device.state().p_DoHo_D[:2]) - 0.03) < 1e-6


def test_crc_errors_are_rejected_counted_and_tolerated_up_to_the_limit(emulator, device):
    device.send(haptic_command([0.1, 0.2, 0.3]))
    before = device.state()
    emulator.corrupt_replies(3)
    for _ in range(3):
        device.send(haptic_command([0.1, 0.2, 0.3]))  # a broken reply: no raise (3 <= 5 in a row)
        assert device.state() is before  # nothing from a broken reply is believed
    assert device.health_counters()["crc_errors"] == 3 and emulator.counts.replies_corrupted == 3
    device.send(haptic_command([0.1, 0.2, 0.3]))
    assert device.state() is not before and device.errors_in_row == 0
    events = device.drain_events()
    assert any(e.kind == "haptic_link" and e.data.get("crc_errors") == 3 for e in events)

    emulator.corrupt_replies(100)
    for _ in range(5):
        device.send(haptic_command([0.1, 0.2, 0.3]))
    with pytest.raises(MasterLostError, match="6 bad replies in a row") as info:
        device.send(haptic_command([0.1, 0.2, 0.3]))
    assert info.value.cause == "errors"
    assert [e.kind for e in device.drain_events()].count("haptic_device_lost") == 1
    # the device still hears us: the plugin wrote zero at once (its replies are what is broken)
    wait_until(
        lambda: not emulator.forces[-1].any() and not emulator.applied_force_D.any(), "no zero force after the loss"
    )


def test_garbage_before_a_reply_is_skipped(emulator, device):
    emulator.garbage_before_reply(b"boot v1.0\r\n\xa5\x5a\x82\x1c" + bytes(range(40)))
    device.send(haptic_command([0.0, 0.0, 1.0]))
    np.testing.assert_array_equal(device.state().p_DoHo_D, emulator.last_reply[0].astype(np.float64))
    assert device.health_counters()["garbage_bytes"] > 0 and device.errors_in_row == 0


def test_the_device_watchdog_zeroes_the_force_when_the_host_goes_quiet(emulator):
    dev = SerialHaptic(emulator.port, watchdog=0.2, read_timeout=READ_TIMEOUT_S)
    dev.open()
    dev.send(haptic_command([1.0, 0.0, 0.0]))
    assert emulator.applied_force_D.tolist() == [1.0, 0.0, 0.0]
    deadline = time.monotonic() + GUARD_S
    while emulator.applied_force_D.any() and time.monotonic() < deadline:
        time.sleep(0.01)  # the host sends nothing: the device's watchdog has to act alone
    assert not emulator.applied_force_D.any() and emulator.counts.watchdog_trips == 1
    dev.send(haptic_command([0.0, 0.0, 0.0]))  # the next state says so, once
    assert dev.status == framing.STATUS_WATCHDOG
    assert [e.kind for e in dev.drain_events()] == ["haptic_device_status"]
    dev.send(haptic_command([0.0, 0.0, 0.0]))
    assert dev.status == 0
    dev.close()


# --------------------------------------------------------------------------- the force limit


def test_no_force_on_the_wire_is_ever_above_the_limit_or_not_finite(emulator, device):
    rng = np.random.default_rng(11)
    magnitudes = 10.0 ** rng.uniform(-3, 300, 400)
    forces = [rng.normal(size=3) * m for m in magnitudes]
    forces += [
        np.array(v)
        for v in (
            [np.nan, 0, 0],
            [np.inf, 1, 1],
            [-np.inf, 0, 0],
            [1e308, -1e308, 1e308],
            [np.nan] * 3,
            [5.0, 0, 0],
            [0, -5.0000001, 0],
            [3.4e38, 0, 0],
            [1e-45, 0, 0],
        )
    ]
    for force in forces:
        device.send(haptic_command(force))
    device.send(haptic_command([4.0, 4.0, 4.0], enabled=False))
    received = np.array(emulator.forces, dtype=np.float64)
    assert len(received) == len(forces) + 1 and np.isfinite(received).all()
    norms = np.linalg.norm(received, axis=1)
    assert norms.max() <= 5.0
    for force, got in zip(forces, received):
        if not np.isfinite(force).all():
            assert not got.any()  # NaN or inf: zero, never a guess
            continue
        scaled = force / np.abs(force).max()  # a direction without overflowing at 1e300 N
        if np.abs(force).max() * np.linalg.norm(scaled) > 5.0:
            assert np.linalg.norm(got) > 5.0 * (1 - 1e-5)  # clamped, not dropped
            np.testing.assert_allclose(got / np.linalg.norm(got), scaled / np.linalg.norm(scaled), atol=1e-6)
    assert not received[-1].any()  # a disabled command writes zero whatever its force says
    assert emulator.counts.clamped == 0  # the device never had to clamp: the host did


def test_the_devices_own_maximum_wins_when_lower(master_emulator):
    with master_emulator(max_force=1.5) as em:
        dev = SerialHaptic(em.port, device_max_force=3.0, read_timeout=READ_TIMEOUT_S)
        dev.open()
        assert dev.max_force == 1.5
        dev.send(haptic_command([0.0, 10.0, 0.0]))
        assert 1.5 * (1 - 1e-5) < np.linalg.norm(em.forces[-1]) <= 1.5 and em.counts.clamped == 0
        dev.close()


def test_clamp_force_keeps_direction_without_overflow():
    out = clamp_force(np.array([1e308, 1e308, 0.0]), 2.0)
    assert out.dtype == np.float32 and np.linalg.norm(out.astype(float)) <= 2.0
    np.testing.assert_allclose(out, [np.sqrt(2), np.sqrt(2), 0.0], rtol=1e-5)
    assert not clamp_force(np.array([1.0, np.nan, 0.0]), 2.0).any()


# --------------------------------------------------------------------------- losing the device


def test_an_unplugged_device_raises_and_stays_lost(emulator, device):
    device.send(haptic_command([0.5, 0.0, 0.0]))
    emulator.unplug()
    with pytest.raises(MasterLostError) as info:
        device.send(haptic_command([0.5, 0.0, 0.0]))
    assert info.value.cause == "gone" and emulator.port in str(info.value)
    for _ in range(3):  # still lost: raised at once, or after a retry that finds the port gone
        with pytest.raises(MasterLostError, match="lost"):
            device.send(haptic_command([0.5, 0.0, 0.0]))
        time.sleep(0.03)
    events = device.drain_events()
    assert [e.kind for e in events].count("haptic_device_lost") == 1
    assert device.health_counters()["losses"] == 1


def test_a_silent_device_is_lost_then_found_again(emulator, device):
    device.send(haptic_command([0.5, 0.0, 0.0]))
    device.link.read_timeout = 0.2  # from here on the timeout is what is tested: make it short
    emulator.stop_answering()
    with pytest.raises(MasterLostError, match="no reply within 200 ms") as info:
        device.send(haptic_command([0.5, 0.0, 0.0]))
    assert info.value.cause == "silent"
    retries, deadline = 0, time.monotonic() + GUARD_S
    while retries < 2 and time.monotonic() < deadline:  # tried again (and waited) twice while still silent
        with pytest.raises(MasterLostError) as info:
            device.send(haptic_command([0.5, 0.0, 0.0]))
        retries += info.value.cause == "silent"  # the others raise at once: "lost", not tried
    assert retries == 2
    emulator.stop_answering(False)
    deadline, back = time.monotonic() + GUARD_S, False
    while not back and time.monotonic() < deadline:
        try:
            device.send(haptic_command([0.5, 0.0, 0.0]))
            back = True
        except MasterLostError:
            time.sleep(0.01)
    assert back
    assert not emulator.forces[-1].any()  # the first force after a loss is zero
    kinds = [e.kind for e in device.drain_events()]
    assert kinds.count("haptic_device_lost") == 1 and kinds.count("haptic_device_back") == 1
    device.send(haptic_command([0.5, 0.0, 0.0]))
    assert emulator.forces[-1].tolist() == [0.5, 0.0, 0.0]


def test_a_restarted_device_gets_a_new_handshake(emulator, device):
    device.send(haptic_command([0.5, 0.0, 0.0]))
    emulator.restart()
    with pytest.raises(MasterLostError, match="forgot the handshake") as info:
        device.send(haptic_command([0.5, 0.0, 0.0]))
    assert info.value.cause == "restarted" and emulator.counts.naks_sent == 1
    wait_until(lambda: not _raises(device, haptic_command([0.5, 0.0, 0.0])), "the device did not come back")
    assert emulator.counts.hellos == 2 and not emulator.forces[-1].any()  # a new HELLO, then zero force first
    kinds = [e.kind for e in device.drain_events()]
    assert kinds.count("haptic_device_lost") == kinds.count("haptic_device_back") == 1


def _raises(device, cmd) -> bool:
    try:
        device.send(cmd)
        return False
    except MasterLostError:
        return True


# --------------------------------------------------------------------------- open and config errors


def test_open_errors_name_the_port_and_the_problem(tmp_path, master_emulator):
    missing = str(tmp_path / "ttyACM9")
    with pytest.raises(MasterOpenError, match=f"^haptic.port {missing}: cannot open: "):
        SerialHaptic(missing).open()
    # the wrong protocol: an Inverse3 ignores our HELLO
    with (
        master_emulator("inverse3") as em,
        pytest.raises(MasterOpenError, match=f"^haptic.port {em.port}: no reply to the hapticlab HELLO"),
    ):
        SerialHaptic(em.port, open_timeout=0.3).open()
    with (
        master_emulator("hapticlab") as em,
        pytest.raises(MasterOpenError, match=r"no reply to the Inverse3 wake-up \(0x0A\)"),
    ):
        SerialHaptic(em.port, "inverse3", open_timeout=0.3).open()
    with master_emulator("hapticlab") as em:  # a port another hapticlab holds
        first = SerialHaptic(em.port)
        first.open()
        with pytest.raises(MasterOpenError, match=f"^haptic.port {em.port}: cannot open: Could not exclusively lock"):
            SerialHaptic(em.port).open()
        first.close()
    with pytest.raises(ConfigError, match=r"^haptic.port: must name the serial device, e.g. --set haptic.port="):
        built()
    with pytest.raises(ConfigError, match=r"^haptic.protocol: must be 'hapticlab' or 'inverse3', got 'ours'$"):
        built(port="/dev/ttyACM0", protocol="ours")


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"rate_hz": 0.0}, "haptic.rate_hz: must be a finite number > 0, got 0.0"),
        ({"read_timeout": float("nan")}, "haptic.read_timeout: must be a finite number > 0, got nan"),
        ({"watchdog": 70.0}, "haptic.watchdog: must be a finite number >= 0 and <= 65.535 s (0: off), got 70.0"),
        ({"baudrate": 0}, "haptic.baudrate: must be a whole number >= 1 (bit/s), got 0"),
        ({"max_consecutive_errors": -1}, "haptic.max_consecutive_errors: must be a whole number >= 0, got -1"),
    ],
)
def test_a_bad_option_is_one_line_naming_the_full_key(options, message):
    with pytest.raises(ConfigError) as info:
        built(port="/dev/ttyACM0", **options)
    assert str(info.value) == message


def test_a_hello_broken_on_the_way_is_sent_again(emulator):
    emulator.corrupt_replies(2)  # the first two HELLO_ACKs arrive broken
    dev = SerialHaptic(emulator.port, read_timeout=READ_TIMEOUT_S)
    dev.open()
    assert emulator.counts.hellos == 3 and dev.health_counters()["crc_errors"] == 2
    dev.close()


def test_a_device_speaking_another_version_is_refused_by_name(pty_pair):
    """A hand-made device on a bare pty answers HELLO with version 2."""
    master, slave = pty_pair
    tty.setraw(slave)

    def answer():
        os.read(master, 64)  # the host's HELLO
        os.write(master, framing.encode_frame(framing.HELLO_ACK, 1, framing.HelloAck(2, 1, 1, 8.0, 1e3).pack()))

    threading.Thread(target=answer, daemon=True).start()
    with pytest.raises(MasterOpenError, match=r"speaks hapticlab protocol version 2, this host speaks 1$"):
        SerialHaptic(os.ttyname(slave), open_timeout=2.0).open()


# --------------------------------------------------------------------------- a session with a serial master


def test_a_session_whose_master_is_unplugged_records_a_zero_force_and_an_event(tmp_path, master_emulator):
    """The demo, its haptics on the emulated master; the cable is pulled 2.6 s in (after the force came on)."""
    from hapticlab.core import hookimpl
    from hapticlab.plugins.sensors.sim import SimSensor
    from hapticlab.sessions.config import apply_overrides, load_config
    from hapticlab.sessions.live import build_session, run_session
    from hapticlab.sessions.recording import read_recording

    with master_emulator("hapticlab", max_force=8.0) as em:

        class CablePuller(SimSensor):
            def __init__(self, rate_hz: float = 1000.0, world=None):
                super().__init__(rate_hz, world=world)
                self.reads = 0

            def read_block(self, until_ns):
                self.reads += 1
                if self.reads == 2600:
                    em.unplug()
                return super().read_block(until_ns)

        class Plugins:
            @hookimpl
            def register_sensors(self, register):
                register("cable_puller", CablePuller)

        pm = make_plugin_manager(load_entry_points=False)
        pm.register(Plugins(), name="tests")
        config, _ = load_config("demo")
        config = apply_overrides(
            config,
            [
                "session.realtime=false",
                "session.duration=3.0",
                "sensor.name=cable_puller",
                "haptic.name=serial",
                f"haptic.port={em.port}",
                "haptic.device_max_force=6.0",
                f"haptic.read_timeout={READ_TIMEOUT_S}",
            ],
        )  # the emulator shares this process's GIL: no loss for a slow reply
        result = run_session(build_session(config, Registry(pm)), out=tmp_path / "unplugged.mcap")
        sent = list(em.forces)
    assert result.error == ""  # a lost master does not end the session
    rec = read_recording(result.path)
    commands = rec.topics["/haptic/command"]
    (lost_event,) = [e for e in result.events if e.kind == "haptic_device_lost"]
    assert lost_event.data["cause"] == "gone"
    t_lost = lost_event.t_ns
    before = [m for t, m in commands if t < t_lost]
    after = [m for t, m in commands if t >= t_lost]
    on = [m for m in before if m["enabled"] and any(m["force_D"])]
    assert on, "the force never came on before the cable was pulled"
    # one force on the wire per tick until the loss, each the session's command to the float32
    np.testing.assert_array_equal(np.array(sent), np.array([m["force_D"] for m in before], dtype=np.float32))
    assert after and all(m["force_D"] == [0.0, 0.0, 0.0] and not m["enabled"] for m in after)
    assert after[0]["reason"].startswith("device error: ") and em.port in after[0]["reason"]
    lost = [m for _, m in rec.topics["/events"] if m["kind"] == "haptic_device_lost"]
    assert len(lost) == 1 and lost[0]["data"]["source"] == "haptic"
    # one event for the loss, not one per tick (or per retry) while it lasts
    assert sum(m["kind"] == "haptic_disabled" and "device error" in m["message"] for _, m in rec.topics["/events"]) == 1
    assert "still lost" in after[-2]["reason"]  # the last tick's (the final command is the session's own zero)
    states = rec.topics["/haptic/state"]
    assert states and max(t for t, _ in states) < t_lost  # no state is made up after the loss


# --------------------------------------------------------------------------- pipelined: never waiting for the wire


def wait_until(condition, what: str):
    deadline = time.monotonic() + GUARD_S
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.002)


def test_pipelined_sends_write_every_force_and_take_replies_as_they_come(emulator):
    dev = SerialHaptic(emulator.port, wait_for_reply=False, read_timeout=READ_TIMEOUT_S)
    dev.open()
    rng = np.random.default_rng(4)
    sent = [rng.uniform(-1.5, 1.5, 3) for _ in range(200)]  # within the 3 N default limit
    for k, force in enumerate(sent):
        dev.send(haptic_command(force, t_ns=k))
    # zero forces until the replies have caught up: all but the newest command or two answered
    wait_until(
        lambda: dev.send(haptic_command([0.0, 0.0, 0.0], t_ns=200)) or len(dev.pipeline.outstanding) <= 1,
        "the replies never caught up",
    )
    np.testing.assert_array_equal(np.array(emulator.forces)[:200], np.array(sent, dtype=np.float32))
    state = dev.state()
    assert state is not None and abs(np.linalg.norm(state.p_DoHo_D[:2]) - 0.03) < 1e-6  # on the emulator's circle
    counters = dev.health_counters()
    assert counters["crc_errors"] == counters["stale_replies"] == counters["bad_replies"] == 0
    dev.close()


def test_pipelined_crc_errors_are_counted_and_a_silent_device_is_lost_without_blocking(emulator):
    dev = SerialHaptic(emulator.port, wait_for_reply=False, read_timeout=READ_TIMEOUT_S)
    dev.open()
    emulator.corrupt_replies(2)
    wait_until(
        lambda: dev.send(haptic_command([0.1, 0.0, 0.0])) or dev.health_counters()["crc_errors"] == 2,
        "the broken replies were not counted",
    )
    assert dev.lost is None
    dev.link.read_timeout = 0.1  # from here on the timeout is what is tested: make it short
    emulator.stop_answering()
    returned = 0
    # the error ends a loop of sends: the loop is what raises
    with pytest.raises(MasterLostError, match="no reply within 100 ms") as info:  # noqa: PT012
        deadline = time.monotonic() + GUARD_S
        while time.monotonic() < deadline:
            dev.send(haptic_command([0.1, 0.0, 0.0]))  # returns at once while the device is quiet ...
            returned += 1
            time.sleep(0.005)
    assert info.value.cause == "silent" and returned >= 2  # ... until its oldest command has waited too long
    dev.close()


def test_pipelining_needs_our_protocol():
    with pytest.raises(ConfigError, match=r'^haptic.wait_for_reply: false needs protocol = "hapticlab"'):
        built(port="/dev/ttyACM0", protocol="inverse3", wait_for_reply=False)
