"""The live loop records its own failures: a part that raises, a loop that falls behind, every estimator's events."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from hapticlab.core import hookimpl
from hapticlab.core.host.registry import ConfigError, Registry, make_plugin_manager
from hapticlab.core.types import Event
from hapticlab.plugins.estimators.rls import RLSEstimator
from hapticlab.plugins.kinematics.sim import SimKinematics
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import SessionError, build_session, run_session
from hapticlab.sessions.recording import read_recording


def demo(*overrides: str, duration: float = 2.0, realtime: bool = False):
    config, _ = load_config("demo")
    return apply_overrides(
        config, [f"session.realtime={str(realtime).lower()}", f"session.duration={duration}", *overrides]
    )


class BreakingSensor(SimSensor):
    """The simulated sensor, whose cable is pulled after ``fail_after`` reads."""

    def __init__(self, rate_hz: float = 1000.0, fail_after: int = 800, world=None):
        super().__init__(rate_hz, world=world)
        self.fail_after, self.reads = fail_after, 0

    def read_block(self, until_ns):
        self.reads += 1
        if self.reads > self.fail_after:
            raise ConnectionResetError("RDT socket closed by the sensor")
        return super().read_block(until_ns)


class BreakingKinematics(SimKinematics):
    def __init__(self, rate_hz: float = 500.0, fail_after: int = 800, world=None):
        super().__init__(rate_hz, world=world)
        self.fail_after, self.reads = fail_after, 0

    def read(self, until_ns):
        self.reads += 1
        if self.reads > self.fail_after:
            raise TimeoutError("RTDE: no data package for 100 ms")
        return super().read(until_ns)


class BreakingEstimator(RLSEstimator):
    def __init__(self, fail_after: int = 800):
        super().__init__()
        self.fail_after, self.calls = fail_after, 0

    def update_block(self, block):
        self.calls += 1
        if self.calls > self.fail_after:
            raise np.linalg.LinAlgError("Singular matrix")
        return super().update_block(block)


class SlowEstimator(RLSEstimator):
    """rls that stalls 30 ms once every 100 updates (a garbage-collection pause, a page fault)."""

    def __init__(self):
        super().__init__()
        self.calls = 0

    def update_block(self, block):
        self.calls += 1
        if self.calls % 100 == 0:
            time.sleep(0.03)
        return super().update_block(block)


class ChattySensor(SimSensor):
    """A sensor that reports an event of its own (EmitsEvents) once, after 100 reads."""

    def __init__(self, rate_hz: float = 1000.0, world=None):
        super().__init__(rate_hz, world=world)
        self.reads, self.pending = 0, []

    def read_block(self, until_ns):
        self.reads += 1
        if self.reads == 100:
            self.pending.append(Event(until_ns, "sensor_status", "temperature compensation active"))
        return super().read_block(until_ns)

    def drain_events(self):
        out, self.pending = self.pending, []
        return out


class NotAnEstimator:
    def __init__(self):
        pass

    def params(self):
        return {}


class Plugins:
    @hookimpl
    def register_sensors(self, register):
        register("breaking", BreakingSensor)
        register("chatty", ChattySensor)

    @hookimpl
    def register_kinematics(self, register):
        register("breaking", BreakingKinematics)

    @hookimpl
    def register_estimators(self, register):
        register("breaking", BreakingEstimator)
        register("slow", SlowEstimator)
        register("broken", NotAnEstimator)


@pytest.fixture
def registry():
    pm = make_plugin_manager(load_entry_points=False)
    pm.register(Plugins(), name="tests")
    return Registry(pm)


@pytest.mark.parametrize(
    ("override", "part", "cause"),
    [
        ("sensor.name=breaking", "sensor breaking", "ConnectionResetError: RDT socket closed"),
        ("kinematics.name=breaking", "kinematics breaking", "TimeoutError: RTDE: no data package"),
        ("estimator.name=breaking", "estimator breaking", "LinAlgError: Singular matrix"),
    ],
)
def test_a_part_that_raises_ends_the_session_with_a_complete_recording(tmp_path, registry, override, part, cause):
    path = tmp_path / "failed.mcap"
    with pytest.raises(SessionError, match=f"^{part} raised {cause}") as info:
        run_session(build_session(demo(override), registry), out=path)
    assert info.value.result.path == path and info.value.part == part
    assert info.value.result.error.startswith(f"{part} raised")
    rec = read_recording(path)  # complete: footer, summary, every topic readable
    summary = rec.metadata["hapticlab.summary"]
    assert summary["interrupted"] == "false" and summary["error"].startswith(f"{part} raised")
    errors = [m for _, m in rec.topics["/events"] if m["kind"] == "error"]
    assert errors and errors[-1]["message"].startswith(part) and errors[-1]["data"]["part"] == part
    assert rec.topics["/events"][-1][1] == {"kind": "session_end", "message": "ended by an error"}
    *_, (_, last) = rec.topics["/haptic/command"]
    assert last["force_D"] == [0.0] * 3 and not last["enabled"]
    assert last["reason"].startswith(f"session ended by an error: {part} raised")
    # the session ran 0.8 s before the failure, and that is all in the file
    assert 0.75 < (rec.t_ns("/sensor/wrench")[-1] - rec.t_ns("/sensor/wrench")[0]) * 1e-9 < 0.85


def test_every_estimators_events_are_recorded_with_their_source(tmp_path, long_session):
    """rls drives the haptics (the preset's rls shadow promoted), kalman runs beside it: kalman's payload change
    is recorded all the same."""
    config = demo("estimator.name=rls", "shadows.kalman={}", duration=12.0)
    config["world"]["contacts"] = [{"kind": "hanging_mass", "start": 9.0, "duration": 1e9, "mass": 0.1}]
    result = long_session(build_session(config), out=tmp_path / "shadow.mcap")
    rec = read_recording(result.path)
    payload = [m for _, m in rec.topics["/events"] if m["kind"] == "payload_change"]
    assert len(payload) == 1 and payload[0]["data"]["source"] == "kalman"
    # a shadow's event does not hold the primary's haptic force
    assert not any(m["reason"].startswith("payload change") for _, m in rec.topics["/haptic/command"])


def test_a_shadow_that_raises_is_dropped_and_the_session_goes_on(tmp_path, registry):
    config = demo("shadows.fragile.name=breaking", "shadows.fragile.fail_after=300", duration=1.0)
    result = run_session(build_session(config, registry), out=tmp_path / "shadow_failed.mcap")
    assert result.error == "" and result.samples == 1001
    rec = read_recording(result.path)
    # 300 updates before it raised: the first tick reads the samples at 0 and 1 ms
    assert len(rec.topics["/estimator/fragile"]) == 301 and len(rec.topics["/estimator/rls"]) == 1001
    (dropped,) = [m for _, m in rec.topics["/events"] if m["kind"] == "error"]
    assert "shadow estimator fragile raised LinAlgError" in dropped["message"]


def test_a_device_event_is_recorded_with_its_source(tmp_path, registry):
    result = run_session(build_session(demo("sensor.name=chatty", duration=0.5), registry), out=tmp_path / "c.mcap")
    (event,) = [e for e in result.events if e.kind == "sensor_status"]
    assert event.data == {"source": "sensor"}


def _session_start_ns(rec) -> int:
    """The session's t0: the stamp of its session_start event (tick k is due k periods after it)."""
    return next(t for t, m in rec.topics["/events"] if m["kind"] == "session_start")


def test_a_realtime_session_runs_on_the_wall_clock(tmp_path, paced_run):
    """A paced session stamps each tick with the wall clock as it runs: after the tick was due (a simulated
    session stamps each exactly when due), and it ends once its duration has passed on that clock."""
    result = paced_run(build_session(demo(duration=0.5, realtime=True)), tmp_path / "rt.mcap")
    rec = read_recording(result.path)
    t0 = _session_start_ns(rec)
    t_cmd = rec.t_ns("/haptic/command")
    ticks = t_cmd[:-1]  # the final zero aside
    # tick k is due at t0 + k ms; the i-th tick run is tick i or later (an overrun skips ticks)
    assert np.all(ticks > t0 + np.arange(1, len(ticks) + 1) * 1_000_000) and np.all(np.diff(t_cmd) > 0)
    assert t_cmd[-1] - t0 >= 500_000_000 and result.duration_s == (t_cmd[-1] - t0) * 1e-9  # the end, on that clock
    # one command per 1 ms tick, except the ticks an overrun skipped (counted in its events), plus the final
    # zero; a loaded machine may leave the last few ticks due when the wall clock reaches the end (not skipped)
    skipped = sum(e.data["ticks_skipped"] for e in result.events if e.kind == "overrun")
    assert 495 <= len(ticks) + skipped <= 501


def test_a_paced_loop_lets_the_simulated_devices_work_ahead_while_it_would_sleep(tmp_path, paced_run):
    session = build_session(demo(duration=2.0, realtime=True))
    where = []
    for device in (session.sensor, session.kinematics):
        compute, prepare = device._ahead.compute, device.prepare
        device._ahead.compute = lambda seq, compute=compute: where.append(preparing[0]) or compute(seq)

        def counted(until_ns, prepare=prepare):
            preparing[0] = True
            try:
                prepare(until_ns)
            finally:
                preparing[0] = False

        device.prepare = counted
    preparing = [False]
    result = paced_run(session, tmp_path / "ahead.mcap")
    # 2 s of 400-sample chunks: 5 of the 1 kHz sensor's, 3 of the 500 Hz poses' (the last ones look ten ticks
    # ahead), computed while the loop had time to spare (a device whose turn found too little, or a tick that
    # overran on a loaded machine, reads without it: the same samples, computed at the read)
    assert len(where) >= 8 and sum(where) >= len(where) // 2
    assert result.samples >= 1995


class LoopClock:
    """The pacer's ``time`` module, keeping the last ``monotonic_ns`` the pacer read (its "now") and the first
    one since ``first_ns`` was cleared (a window's first look)."""

    def __init__(self):
        self.last_ns = 0
        self.first_ns: int | None = None

    def monotonic_ns(self) -> int:
        self.last_ns = time.monotonic_ns()
        if self.first_ns is None:
            self.first_ns = self.last_ns
        return self.last_ns

    def __getattr__(self, name):
        return getattr(time, name)


def test_a_paced_loop_asks_ten_ticks_ahead_and_only_with_half_a_period_to_spare(tmp_path, paced_run, monkeypatch):
    """A device's work ahead waits for an idle moment: each is asked only while half a period is left, so a
    slow one (here the sensor's, 0.6 ms a call) leaves the other (the poses') no turn in its window. What is
    left is the pacer's own: its clock read, the one it decided on."""
    from hapticlab.sessions.live import pacing
    from hapticlab.sessions.live.pacing import PREPARE_AHEAD_TICKS

    clock = LoopClock()
    monkeypatch.setattr(pacing, "time", clock)
    session = build_session(demo(duration=0.5, realtime=True))
    period_ns = 1_000_000
    spare = []  # per window: the time left before its tick when the pacer first looked, ns
    next_tick = pacing.Pacer.next_tick

    def watched(pacer, tick):
        clock.first_ns = None
        out = next_tick(pacer, tick)
        if clock.first_ns is not None:  # (None: not paced yet)
            spare.append(pacer.t0_ns + (tick + 1) * pacer.period_ns - clock.first_ns)
        return out

    monkeypatch.setattr(pacing.Pacer, "next_tick", watched)
    calls = []
    for part, device, slow in (("sensor", session.sensor, True), ("kinematics", session.kinematics, False)):

        def recorded(until_ns, prepare=device.prepare, part=part, slow=slow):
            calls.append((part, until_ns - PREPARE_AHEAD_TICKS * period_ns - clock.last_ns))  # (due - now)
            if slow:
                time.sleep(0.0006)
            prepare(until_ns)

        device.prepare = recorded
    result = paced_run(session, tmp_path / "turns.mcap")
    sensor = [left for part, left in calls if part == "sensor"]
    # asked in every window the pacer found half a period to spare in, and in no other (how many there were
    # is the machine's pace: the recording's ticks say the same)
    assert len(sensor) == sum(left >= period_ns // 2 for left in spare) >= 10, (len(sensor), len(spare))
    assert all(left >= period_ns // 2 for _, left in calls)  # half a period left, as the loop saw it
    assert [part for part, _ in calls].count("kinematics") < len(sensor) // 10  # rarely a turn after the sensor
    assert result.samples >= 495  # the poses computed at their reads instead: the same samples


def test_a_loop_that_falls_behind_records_an_overrun(tmp_path, registry, paced_run):
    config = demo("estimator.name=slow", duration=1.0, realtime=True)
    result = paced_run(build_session(config, registry), tmp_path / "slow.mcap")
    overruns = [e for e in result.events if e.kind == "overrun"]
    assert result.overruns >= 1 and overruns
    # a 30 ms stall at 1 kHz: at least 20 ms behind, 20 ticks skipped (the events add up every overrun)
    assert max(e.data["behind_s"] for e in overruns) >= 0.02
    assert sum(e.data["ticks_skipped"] for e in overruns) >= 20
    assert all("behind its 1000 Hz rate" in e.message for e in overruns)
    # no command was sent for the ticks it skipped: the loop did not replay them back to back
    t_cmd = read_recording(result.path).t_ns("/haptic/command")
    assert np.diff(t_cmd).max() >= 0.02e9


def test_a_plugin_without_its_interface_is_refused_at_build_time(registry):
    with pytest.raises(
        ConfigError,
        match=r"^estimator.name: estimator 'broken' \(tests\) is not a Estimator: "
        r"it lacks update_block$",
    ):
        build_session(demo("estimator.name=broken"), registry)


def _writer_processes() -> list[int]:
    """This process's children running the recording's writer (sessions/recording/sinks.py)."""
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmdline = f.read()
        except (FileNotFoundError, ProcessLookupError):
            continue
        if ppid == os.getpid() and b"sinks.py" in cmdline:
            pids.append(int(entry))
    return pids


class WriterKillingSensor(SimSensor):
    """The simulated sensor; after ``kill_after`` reads it kills the session's writer process (a crash, the OOM
    killer)."""

    def __init__(self, rate_hz: float = 1000.0, kill_after: int = 500, world=None):
        super().__init__(rate_hz, world=world)
        self.kill_after, self.reads = kill_after, 0

    def read_block(self, until_ns):
        self.reads += 1
        if self.reads == self.kill_after:
            (pid,) = _writer_processes()
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)  # dead and reaped before the loop hands it the next tick
        return super().read_block(until_ns)


class CommandLog:
    """A haptic device that keeps every command it is sent."""

    rate_hz = 1000.0

    def __init__(self):
        self.commands, self.closed = [], False

    def open(self):
        pass

    def send(self, command):
        self.commands.append(command)

    def state(self):
        return None

    def close(self):
        self.closed = True


def test_a_writer_process_that_dies_ends_the_session_with_the_force_zeroed(tmp_path):
    """The recording's writer process killed mid-session: zero force sent, devices closed, the error named."""
    device = CommandLog()

    class Killer:
        @hookimpl
        def register_sensors(self, register):
            register("writer_killer", WriterKillingSensor)

        @hookimpl
        def register_haptic_outputs(self, register):
            register("log", lambda: device)

    pm = make_plugin_manager(load_entry_points=False)
    pm.register(Killer(), name="tests")
    path = tmp_path / "writer_died.mcap"
    with pytest.raises(SessionError, match=r"^recording raised WriterProcessError.*hapticlab recover") as info:
        run_session(
            build_session(demo("sensor.name=writer_killer", "haptic.name=log", duration=2.0), Registry(pm)), out=path
        )
    assert info.value.part == "recording"
    assert device.closed and device.commands[-1].reason.startswith("session ended by an error: recording raised")
    assert not device.commands[-1].enabled and not device.commands[-1].force_D.any()
    assert len(device.commands) < 600  # it ended at the tick the writer was found dead, not at 2 s
    assert _writer_processes() == []


class NetworkedSensor(SimSensor):
    """A sensor that learns its calibration when opened and reports its final counters when closed."""

    def __init__(self, rate_hz: float = 1000.0, world=None):
        super().__init__(rate_hz, world=world)
        self.calibration = {"source": "not read yet"}
        self.pending = []

    def open(self, t0_ns):
        super().open(t0_ns)
        self.calibration = {"source": "sensor", "counts_per_force": "1000000"}

    def close(self):
        self.pending.append(Event(0, "sensor_health", "final counters", {"lost": 3}))

    def drain_events(self):
        out, self.pending = self.pending, []
        return out


def test_the_calibration_read_at_open_and_the_events_of_closing_are_recorded(tmp_path):
    class Networked:
        @hookimpl
        def register_sensors(self, register):
            register("networked", NetworkedSensor)

    pm = make_plugin_manager(load_entry_points=False)
    pm.register(Networked(), name="tests")
    result = run_session(
        build_session(demo("sensor.name=networked", duration=0.2), Registry(pm)), out=tmp_path / "net.mcap"
    )
    rec = read_recording(result.path)
    assert rec.metadata["hapticlab.calibration"] == {"source": "sensor", "counts_per_force": "1000000"}
    health = [m for _, m in rec.topics["/events"] if m["kind"] == "sensor_health"]
    assert health == [{"kind": "sensor_health", "message": "final counters", "data": {"lost": 3, "source": "sensor"}}]


class UnpluggedMaster(CommandLog):
    """A master device whose port is not there."""

    def open(self):
        raise FileNotFoundError("[Errno 2] No such file or directory: '/dev/ttyACM7'")


def test_a_master_that_does_not_open_ends_the_session_with_a_complete_recording(tmp_path):
    """The haptic device's open fails like the sensor's: named, the file finished, no writer left behind."""
    device = UnpluggedMaster()

    class Unplugged:
        @hookimpl
        def register_haptic_outputs(self, register):
            register("unplugged", lambda: device)

    pm = make_plugin_manager(load_entry_points=False)
    pm.register(Unplugged(), name="tests")
    path = tmp_path / "unplugged.mcap"
    with pytest.raises(SessionError, match=r"^haptic unplugged raised FileNotFoundError.*ttyACM7") as info:
        run_session(build_session(demo("haptic.name=unplugged"), Registry(pm)), out=path)
    assert info.value.part == "haptic unplugged" and device.closed
    rec = read_recording(path)  # complete
    assert rec.metadata["hapticlab.summary"]["error"].startswith("haptic unplugged raised")
    assert _writer_processes() == []


def test_a_paced_session_freezes_the_heap_while_it_runs_and_gives_it_back(tmp_path, paced_run):
    """Full collections skip what was built before the first tick (gc.freeze), only while the session runs."""
    import gc

    session = build_session(demo(duration=0.3, realtime=True))
    frozen = []
    send = session.haptic.send
    session.haptic.send = lambda command: frozen.append(gc.get_freeze_count()) or send(command)
    assert gc.get_freeze_count() == 0
    paced_run(session, tmp_path / "frozen.mcap")
    assert min(frozen) > 10_000  # numpy, numba and the plugins: tens of thousands of objects
    assert gc.get_freeze_count() == 0


def test_a_paced_session_runs_the_tick_due_at_its_end_and_reads_every_sample_up_to_it(tmp_path, paced_run):
    """Sample i of a 1 kHz sensor is stamped i ms after the start: a 0.2 s paced session reads 0..200, the
    one stamped at its very end included (the tick due then runs, a moment after it is due)."""
    result = paced_run(build_session(demo(duration=0.2, realtime=True)), tmp_path / "end.mcap")
    assert result.samples == 201 or result.overruns  # (a loop that fell behind past its end skips that tick)
    rec = read_recording(result.path)
    t0 = _session_start_ns(rec)
    commands = rec.t_ns("/haptic/command")
    reasons = [m["reason"] for _, m in rec.messages("/haptic/command")]
    assert (np.diff(commands) >= 0).all() and reasons[-1] == "session ended"  # the final zero, last of all
    # it ends with the tick due at 0.2 s: that tick ran once due (unless skipped), none after it, then the end
    assert commands[-2] - t0 >= 200_000_000 or result.overruns
    assert len(commands) - 1 <= 200
    assert commands[-1] - t0 >= 200_000_000 and result.duration_s == (commands[-1] - t0) * 1e-9
