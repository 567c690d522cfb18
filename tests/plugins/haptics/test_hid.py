"""The ``hid`` haptic master: layouts, quantisation, limits, losses, over the fake RawHID master (no uhid here)."""

from __future__ import annotations

import copy
import struct

import numpy as np
import pytest

from hapticlab.core.host.interfaces import EmitsEvents, HapticOutput, ReportsHealth
from hapticlab.core.host.options import OptionError
from hapticlab.core.host.registry import ConfigError, Registry, make_plugin_manager
from hapticlab.core.types import HapticCommand
from hapticlab.plugins.haptics.hid import HidHaptic
from hapticlab.plugins.haptics.hid_fake import FakeHidapi, FakeRawHidMaster
from hapticlab.plugins.haptics.hid_layout import PRESETS, TYPES, Field, RawHidLayout, encode_force
from hapticlab.plugins.haptics.hid_transport import DeviceSelector, HidapiTransport
from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError, clamp_force

TEENSY = PRESETS["teensy-rawhid"]["layout"]


def command(force, t_ns=0, enabled=True):
    return HapticCommand(t_ns, np.asarray(force, dtype=float), enabled)


def built(**options):
    """The hid plugin as a session builds it from ``[haptic]``: an option error names the full key."""
    return Registry(make_plugin_manager(load_entry_points=False)).create(
        "haptic_output", "hid", options, where="haptic"
    )


def with_change(path: str, value):
    """The Teensy layout with one key (dotted path) set; value None deletes it."""
    layout = copy.deepcopy(TEENSY)
    *parents, last = path.split(".")
    node = layout
    for key in parents:
        node = node[key]
    if value is None:
        del node[last]
    else:
        node[last] = value
    return layout


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (
            "out.force_y",
            {"offset": 2, "type": "f32le"},
            "haptic.layout.out.force_y: bytes 2..5 overlap force_x (bytes 0..3)",
        ),
        (
            "in.echo",
            {"offset": 62, "type": "u32le"},
            "haptic.layout.in.echo.offset: bytes 62..65 end past the 64-byte report",
        ),
        (
            "in.position_x",
            {"offset": 0, "type": "f16le"},
            "haptic.layout.in.position_x.type: must be 'u8', 'i8', 'u16le', 'i16le', 'u32le', 'i32le', 'u16be', "
            "'i16be', 'u32be', 'i32be', 'f32le', 'f32be', 'f64le' or 'f64be', got 'f16le'",
        ),
        ("out.force_z", None, "haptic.layout.out.force_z: required"),
        ("in.wobble", {"offset": 40, "type": "u8"}, "haptic.layout.in.wobble: unknown field"),
        ("in.velocity_z", None, "haptic.layout.in.velocity_z: required with velocity_x"),
        ("out.seq", None, "haptic.layout.in.echo: needs a seq field"),
        (
            "in.buttons",
            {"offset": 18, "type": "i8"},
            "haptic.layout.in.buttons.type: must be 'u8', 'u16le', 'u32le', 'u16be' or 'u32be' (buttons is a count), "
            "got 'i8'",
        ),
        (
            "in.position_y",
            {"offset": 4, "type": "i32le", "scale": 0},
            "haptic.layout.in.position_y.scale: must be a finite",
        ),
        (
            "report_id",
            300,
            "haptic.layout.report_id: must be a whole number >= 0 and <= 255 (0: unnumbered reports), got 300",
        ),
    ],
)
def test_layout_errors_are_one_line_naming_the_key(path, value, message):
    with pytest.raises(ConfigError) as info:
        built(layout=with_change(path, value), vendor_id=1, product_id=2, transport="fake")
    assert str(info.value).startswith(message) and "\n" not in str(info.value)
    with pytest.raises(
        OptionError
    ) as info:  # the layout alone names its keys from "layout"; the session adds "haptic."
        RawHidLayout.from_config(with_change(path, value))
    assert str(info.value.under("haptic")).startswith(message)


def test_a_force_field_that_cannot_hold_the_device_maximum_is_refused():
    layout = with_change("out.force_x", {"offset": 0, "type": "i16le", "scale": 1e-4})  # reaches 3.2767 N
    with pytest.raises(
        ConfigError, match=r"^haptic.layout.out.force_x: i16le at 0.0001 N per count reaches only 3.2767 N"
    ):
        built(layout=layout, vendor_id=1, product_id=2, device_max_force=5.0, transport="fake")
    with pytest.raises(ConfigError, match=r"^haptic.vendor_id: must be given with a layout table \(or haptic.path\)"):
        built(layout=TEENSY)


def test_the_plugin_is_registered_and_has_its_capabilities():
    dev = Registry(make_plugin_manager(load_entry_points=False)).create(
        "haptic_output", "hid", {"transport": "fake"}, where="haptic"
    )
    assert isinstance(dev, HapticOutput) and isinstance(dev, EmitsEvents) and isinstance(dev, ReportsHealth)


def test_round_trip_through_the_fake_master():
    dev = HidHaptic(transport="fake")
    dev.open()
    rng = np.random.default_rng(1)
    for k in range(100):
        force = rng.uniform(-1.5, 1.5, 3)
        dev.send(command(force, t_ns=k))
        np.testing.assert_array_equal(dev.fake.forces[-1], force.astype(np.float32))  # f32: bit-exact
        state = dev.state()
        assert state.t_ns == k
        # the pose the fake integrated, through i32 µm and i16 mm/s: within one count
        np.testing.assert_allclose(state.p_DoHo_D, dev.fake.p_DoHo_D, atol=1e-6)
        np.testing.assert_allclose(state.v_DHo_D, dev.fake.v_DHo_D, atol=1e-3)
    assert np.abs(dev.fake.p_DoHo_D).max() > 1e-4  # the handle did move
    assert dev.health_counters()["stale_reports"] == 0
    dev.close()
    assert not dev.fake.forces[-1].any()  # close writes zero


def test_integer_force_fields_round_within_one_count_and_saturate_instead_of_wrapping():
    layout = copy.deepcopy(TEENSY)
    for i, axis in enumerate("xyz"):
        layout["out"][f"force_{axis}"] = {"offset": 2 * i, "type": "i16le", "scale": 1e-3}
    layout["out"]["seq"] = {"offset": 6, "type": "u16le"}
    layout["out"]["flags"] = {"offset": 8, "type": "u8"}
    dev = HidHaptic(layout=layout, vendor_id=0x16C0, product_id=0x0486, device_max_force=30.0, transport="fake")
    dev.open()
    for force in ([1.2344, -0.0006, 2.5], [17.0, -20.0, 3.0]):
        dev.send(command(force))
        np.testing.assert_allclose(dev.fake.forces[-1], force if np.linalg.norm(force) <= 30 else None, atol=1e-3)
        assert np.linalg.norm(dev.fake.forces[-1]) <= 30.0
    f = Field("force_x", 0, TYPES["i16le"], 1e-3)
    buf = bytearray(2)
    for value, counts in (
        (40.0, 32767),
        (-40.0, -32768),
        (1e300, 32767),
        (-1e300, -32768),
        (float("-inf"), 0),
        (float("nan"), 0),
    ):
        f.pack_into(buf, value)
        assert struct.unpack("<h", buf)[0] == counts  # never wrapped around


def test_nan_and_huge_forces_never_reach_the_wire():
    dev = HidHaptic(transport="fake", device_max_force=2.0)
    dev.open()
    for force in ([np.nan, 1.0, 0.0], [np.inf, 0, 0], [1e300, -1e300, 5.0], [3.4e38, 0, 0], [1.9, 0.6, 0.0]):
        dev.send(command(force))
        got = dev.fake.forces[-1]
        assert np.isfinite(got).all() and np.linalg.norm(got) <= 2.0
        if not np.isfinite(force).all():
            assert not got.any()
    dev.send(command([1e300, -1e300, 0.0]))
    np.testing.assert_allclose(
        dev.fake.forces[-1] / np.linalg.norm(dev.fake.forces[-1]), [2**-0.5, -(2**-0.5), 0], atol=1e-6
    )  # direction kept
    dev.send(command([1.0, 1.0, 1.0], enabled=False))
    assert not dev.fake.forces[-1].any()
    assert dev.fake.counts["clamped"] == 0  # the device never had to clamp


def test_rounding_that_would_exceed_the_limit_goes_toward_zero():
    layout = RawHidLayout.from_config(TEENSY).out
    i16 = RawHidLayout.from_config(with_change("out.force_x", {"offset": 0, "type": "i16le", "scale": 0.1})).out
    for out in (layout, i16):
        data = encode_force(out, clamp_force(np.array([2.96, 0.0, 0.49]), 3.0), 3.0)  # norm 3.0 - 3e-6
        decoded = [out.fields[n].unpack(data) for n in ("force_x", "force_y", "force_z")]
        assert np.linalg.norm(decoded) <= 3.0


def test_stale_and_wrong_id_reports_are_skipped_and_counted():
    layout = with_change("report_id", 7)
    dev = HidHaptic(layout=layout, vendor_id=1, product_id=2, transport="fake", read_timeout=0.02)
    dev.open()
    dev.send(command([0.1, 0, 0]))
    dev.fake.go_silent(1)
    with pytest.raises(MasterLostError, match="no IN report"):
        dev.send(command([0.2, 0, 0]))
    assert not dev.fake.forces[-1].any()  # a silent device is sent zero at once
    dev.next_try = 0.0
    dev.fake.inbox.clear()
    dev.send(command([0.3, 0, 0]))  # a try: back
    assert [e.kind for e in dev.drain_events()][:2] == ["haptic_device_lost", "haptic_device_back"]
    dev.fake.send_stale(1)
    with pytest.raises(MasterLostError):
        dev.send(command([0.4, 0, 0]))
    assert dev.health_counters()["stale_reports"] == 1
    dev.next_try = 0.0
    dev.send(command([0.0, 0, 0]))
    dev.fake.send_wrong_id(2)
    with pytest.raises(MasterLostError):
        dev.send(command([0.5, 0, 0]))
    assert dev.health_counters()["wrong_report_id"] == 1


def test_an_unplugged_device_raises_and_stays_lost_until_it_is_back():
    dev = HidHaptic(transport="fake", reconnect_interval=0.01)
    dev.open()
    dev.send(command([1.0, 0, 0]))
    dev.fake.unplug()
    with pytest.raises(MasterLostError, match="write failed: libusb: LIBUSB_ERROR_NO_DEVICE") as info:
        dev.send(command([1.0, 0, 0]))
    assert info.value.cause == "gone"
    with pytest.raises(MasterLostError, match="still lost"):
        dev.send(command([1.0, 0, 0]))
    dev.fake.replug()
    dev.next_try = 0.0
    dev.send(command([1.0, 0, 0]))
    assert not dev.fake.forces[-1].any()  # the first force after a loss is zero
    kinds = [e.kind for e in dev.drain_events()]
    assert kinds.count("haptic_device_lost") == 1 and kinds.count("haptic_device_back") == 1


def test_opening_chooses_by_ids_serial_and_usage_page():
    layout = RawHidLayout.from_config(TEENSY)
    a = FakeRawHidMaster(layout, serial="A", path=b"p-a")
    b = FakeRawHidMaster(layout, serial="B", path=b"p-b")
    seremu = FakeRawHidMaster(layout, serial="A", path=b"p-seremu", usage_page=0xFFC9, usage=0x0004)
    bus = FakeHidapi([a, b, seremu])
    with pytest.raises(MasterOpenError, match="2 devices match"):
        HidapiTransport(bus).open(DeviceSelector(0x16C0, 0x0486, usage_page=0xFFAB))
    assert "p-a" in HidapiTransport(bus).open(DeviceSelector(0x16C0, 0x0486, "A", usage_page=0xFFAB))
    with pytest.raises(MasterOpenError, match="no HID device 1234:5678"):
        HidapiTransport(bus).open(DeviceSelector(0x1234, 0x5678))
    a.unplug()
    with pytest.raises(MasterOpenError, match="cannot open HID device p-a"):
        HidapiTransport(bus).open(DeviceSelector(path="p-a"))


def test_a_session_whose_hid_master_is_unplugged_records_zero_force_and_an_event(tmp_path):
    from hapticlab.sessions.config import apply_overrides, load_config
    from hapticlab.sessions.live import build_session, run_session
    from hapticlab.sessions.recording import read_recording

    config, _ = load_config("demo")
    config = apply_overrides(
        config,
        [
            "session.realtime=false",
            "session.duration=3.0",
            "haptic.name=hid",
            "haptic.transport=fake",
            "haptic.device_max_force=6.0",
            'haptic.fake_faults=["unplug@2600"]',
        ],
    )
    session = build_session(config, Registry(make_plugin_manager(load_entry_points=False)))
    fake = session.haptic.fake
    result = run_session(session, out=tmp_path / "hid.mcap")
    assert result.error == ""
    rec = read_recording(result.path)
    commands = rec.topics["/haptic/command"]
    (lost,) = [e for e in result.events if e.kind == "haptic_device_lost"]
    assert lost.data["cause"] == "gone"
    before = [m for t, m in commands if t < lost.t_ns]
    after = [m for t, m in commands if t >= lost.t_ns]
    assert any(m["enabled"] and any(m["force_D"]) for m in before), "the force never came on"
    # every force the device decoded is the session's command (f32), one per tick, then nothing more
    wire = np.array(fake.forces[1:])  # the first is open()'s zero
    np.testing.assert_array_equal(wire, np.array([m["force_D"] for m in before], dtype=np.float32))
    assert after and all(m["force_D"] == [0.0, 0.0, 0.0] and not m["enabled"] for m in after)
    assert after[0]["reason"].startswith("device error: ")
    events = [m for _, m in rec.topics["/events"]]
    assert sum(m["kind"] == "haptic_device_lost" for m in events) == 1
    assert sum(m["kind"] == "haptic_disabled" and "device error" in m["message"] for m in events) == 1
