"""``hapticlab bench loop``: where a tick of the run loop goes, and what each estimator costs per sample.

Three tables, so the next change to the hot path is measured the same way:

* **per stage**: the demo session run as fast as the machine allows (``realtime
  = false``, recording on) at a 1 kHz loop with the sensor at 1 kHz and at
  7 kHz. Each stage's calls are timed in place (the loop's own objects wrapped
  with a ``perf_counter_ns`` stopwatch, nothing else changed): sensor read,
  kinematics read, aligner, estimator (the primary's ``update_block``), gate
  and watches, governor, device, recording (the taps: encoding, and the MCAP
  writes with the writer inline, or the hand-over of the tick's batch to the
  writer process); "loop body" is the rest of the tick. Each rate runs with
  the MCAP writer on the loop's thread (``inline``) and in its own process
  (``process``, the default), side by side. µs per tick and share of the
  tick, and the loop's speed (simulated seconds per wall second of its ticks;
  above 1 it keeps up in real time). The session's start and end (opening the
  recording, which with the writer process starts that process; opening the
  devices; finishing the file) are counted once, in ms, apart from the ticks
  (spread over a short run's ticks they would swamp the stages), with the
  whole run's speed beside them. The stopwatches cost time themselves, so
  each session then runs again with only its ticks timed ("no stopwatches"):
  the loop's own speed, which the speed targets are about;
* **per stage, teleoperation**: the same for ``teleop-emulated`` (the simulated
  robot following a master whose handle presses 5 cm down and back every 2 s
  once the calibration tour is over, :class:`PressingHand`; ``kalman`` with the
  ``rls`` shadow, the preset's own), 1 kHz sensor, writer process: its rows
  add the shadow estimators and the teleoperation step (the robot's next
  target and ``servo_cp``); the simulated sensor and robot's physics is
  computed one sample at a time there (it cannot run ahead of a robot that
  follows the hand; only their noise is computed ahead);
* **per estimator**: µs per sample at block sizes 1 (a 1 kHz sensor read at
  1 kHz), 7 (a 7 kHz Net F/T) and 1024 (offline), median and p99 over the
  converged second half of a simulated tour, for each estimator named.

Numbers depend on the machine and its load: quote them, never assert them.
A paced session measured from inside is :mod:`~hapticlab.sessions.bench.realtime`.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.registry import Registry, make_plugin_manager
from hapticlab.core.types import AlignedSamples, DeviceState, HapticCommand
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.bench.simulation import simulate
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.live.loop import LiveLoop

STAGES = (
    "sensor read",
    "kinematics read",
    "aligner",
    "estimator",
    "gate and watches",
    "governor",
    "device",
    "teleoperation",
    "shadow estimators",
    "recording",
    "loop body",
)
"""The table's rows, in the order of a tick (the loop body last: what the stopwatches leave)."""
BLOCK_SIZES = (1, 7, 1024)


class _Stopwatch:
    """Accumulated ns per stage; ``wrap`` puts one around a bound method."""

    def __init__(self):
        self.ns = dict.fromkeys(STAGES, 0)

    def wrap(self, obj: Any, method: str, stage: str) -> None:
        inner = getattr(obj, method)
        ns = self.ns
        clock = time.perf_counter_ns

        def timed(*args, **kwargs):
            t0 = clock()
            try:
                return inner(*args, **kwargs)
            finally:
                ns[stage] += clock() - t0

        setattr(obj, method, timed)


TOUR_OVERRIDES = ("teleop.calibration_dwell_s=0.3", "teleop.max_angular_speed=3.0")
"""The teleoperation table's calibration tour, shortened to ~4 s (the hand takes over for the rest)."""


class PressingHand:
    """A master device for the teleoperation table (HapticOutput, no wire): its handle rests for ``rest_s``
    of session time (the calibration tour), then presses ``depth`` m down along D's −z and back every
    ``period`` s (``scripted_motion("press")``); it renders nothing."""

    def __init__(self, rest_s: float = 4.5, depth: float = 0.05, period: float = 2.0, rate_hz: float = 1000.0):
        from hapticlab.plugins.haptics.handle_motion import scripted_motion

        self.rate_hz, self.rest_s = rate_hz, rest_s
        self.motion = scripted_motion("press", depth, period)
        self.t0_ns: int | None = None
        self.t_ns = 0

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def send(self, command: HapticCommand) -> None:
        if self.t0_ns is None:
            self.t0_ns = command.t_ns
        self.t_ns = command.t_ns

    def state(self) -> DeviceState | None:
        if self.t0_ns is None:
            return None
        p, v = self.motion(max((self.t_ns - self.t0_ns) * 1e-9 - self.rest_s, 0.0))
        return DeviceState(self.t_ns, np.array([1.0, 0.0, 0.0, 0.0]), p, v_DHo_D=v)


class _BenchHand:
    @hookimpl
    def register_haptic_outputs(self, register):
        register("bench_pressing_hand", PressingHand)


def stage_table(
    sensor_rate_hz: float,
    duration_s: float = 5.0,
    estimator: str | None = "rls",
    writer: str = "process",
    preset: str = "demo",
    stopwatches: bool = True,
) -> dict[str, Any]:
    """One non-realtime session of ``preset`` ("demo" or "teleop-emulated", with :class:`PressingHand` as
    its master) with every stage timed: µs per tick and share per stage, speed. ``estimator`` None keeps
    the preset's own (and its shadows). ``stopwatches`` False times the ticks alone (the loop's own speed,
    without the stopwatches' own cost), every stage then in "loop body"."""
    config, _ = load_config(preset)
    overrides = [
        "session.realtime=false",
        f"sensor.rate_hz={float(sensor_rate_hz)}",
        f"session.recording_writer={writer}",
    ]
    if estimator is not None:
        overrides.append(f"estimator.name={estimator}")
    registry = None
    if config.get("teleop", {}).get("enabled"):
        pm = make_plugin_manager()
        pm.register(_BenchHand(), name="bench-hand")
        registry = Registry(pm)
        overrides += ["haptic.name=bench_pressing_hand", *TOUR_OVERRIDES]
    config = apply_overrides(config, overrides)
    session = build_session(config, registry)
    with tempfile.TemporaryDirectory() as folder:
        loop = LiveLoop(session, Path(folder) / "bench.mcap", duration_s, None, 0.25)
        watch = _Stopwatch()
        run = loop.run

        def run_timed():
            # the taps exist once the recording is open: wrap them (and the rest) when the loop starts
            original_open = loop._open

            def open_and_wrap():
                original_open()
                if stopwatches:
                    _wrap_loop(loop, watch)

            loop._open = open_and_wrap
            return run()

        ticks_ns = [0]
        tick = loop._tick

        def timed_tick(now_ns):
            t0 = time.perf_counter_ns()
            try:
                tick(now_ns)
            finally:
                ticks_ns[0] += time.perf_counter_ns() - t0

        loop._tick = timed_tick  # type: ignore[method-assign]  # the bench times every tick
        t0 = time.perf_counter_ns()
        result = run_timed()
        wall_ns = time.perf_counter_ns() - t0
    ticks = max(round(duration_s * session.settings.loop_rate_hz), 1)
    tick_ns = ticks_ns[0]
    timed = sum(watch.ns[s] for s in STAGES if s != "loop body")
    watch.ns["loop body"] = max(tick_ns - timed, 0)
    return {
        "preset": preset,
        "sensor_rate_hz": sensor_rate_hz,
        "loop_rate_hz": session.settings.loop_rate_hz,
        "estimator": session.primary.label,
        "shadows": [shadow.label for shadow in session.shadows],
        "writer": writer,
        "duration_s": duration_s,
        "samples": result.samples,
        "ticks": ticks,
        "contact_samples": loop.contact_samples,  # the primary estimator's (a teleoperated press: the tissue)
        "x_real_time": duration_s / (tick_ns * 1e-9),
        "start_end_ms": (wall_ns - tick_ns) * 1e-6,
        "x_real_time_session": duration_s / (wall_ns * 1e-9),
        "us_per_tick": {s: watch.ns[s] / ticks / 1e3 for s in STAGES},
        "share": {s: watch.ns[s] / tick_ns for s in STAGES},
    }


def _wrap_loop(loop: LiveLoop, watch: _Stopwatch) -> None:
    s = loop.s
    watch.wrap(loop, "read_wrenches", "sensor read")  # the sensor's read_block, or its read made a block
    watch.wrap(s.kinematics, "read", "kinematics read")
    for method in ("align", "add_poses"):
        watch.wrap(loop.aligner, method, "aligner")
    watch.wrap(s.primary.estimator, "update_block", "estimator")
    for method in ("on_poses", "on_samples", "on_estimates", "on_withheld", "reason", "fault_event"):
        watch.wrap(loop.gate, method, "gate and watches")
    watch.wrap(loop.commander.governor, "command", "governor")
    for method in ("send", "state"):
        watch.wrap(s.haptic, method, "device")
    if loop.commander.teleop is not None:
        watch.wrap(loop.commander.teleop, "step", "teleoperation")
        watch.wrap(s.robot, "servo_cp", "teleoperation")
    for shadow in s.shadows:
        watch.wrap(shadow.estimator, "update_block", "shadow estimators")
    for method in (
        "poses",
        "wrenches",
        "aligned",
        "estimates",
        "command",
        "device_state",
        "event",
        "send",
    ):  # the taps queue; send encodes the tick's messages and hands them to the writer
        watch.wrap(loop.taps, method, "recording")


def per_sample_us(factory: Callable[[], Any], block: AlignedSamples, size: int) -> tuple[float, float]:
    """(median, p99) µs per sample of ``update_block`` in blocks of ``size``, over the stream's second half
    (converged: the estimator's ordinary work, not its start)."""
    est = factory()
    times = []
    for i in range(0, len(block) - size + 1, size):
        part = block.subset(slice(i, i + size))
        t0 = time.perf_counter_ns()
        est.update_block(part)
        times.append((time.perf_counter_ns() - t0) / size / 1e3)
    converged = np.array(times[len(times) // 2 :])
    return float(np.median(converged)), float(np.percentile(converged, 99))


def estimator_table(
    factories: dict[str, Callable[[], Any]], samples: int = 20480, sizes: tuple[int, ...] = BLOCK_SIZES
) -> dict[str, dict[int, tuple[float, float]]]:
    """µs per sample (median, p99) per estimator and block size, on a seeded simulated tour (1 kHz)."""
    block, _ = simulate(SimWorld(seed=1, inertia=False), samples / 1000.0, 1000.0)
    return {
        label: {size: per_sample_us(factory, block, size) for size in sizes} for label, factory in factories.items()
    }


def default_estimators() -> dict[str, Callable[[], Any]]:
    """The estimators the table shows: ``rls``, ``kalman`` and ``kalman`` with its inertia model (the
    costliest option), each compiled (the default) and as its numpy reference (``kernel = "numpy"``)."""
    registry = Registry()
    out: dict[str, Callable[[], Any]] = {}
    for label, name, options in (
        ("rls", "rls", {}),
        ("kalman", "kalman", {}),
        ("kalman, inertia", "kalman", {"inertia": True}),
    ):
        for kernel in ("numba", "numpy"):
            out[f"{label} ({kernel})"] = partial(
                registry.create, "estimator", name, {"kernel": kernel, **options}, where="estimator"
            )
    return out


def bench_loop(
    rates: tuple[float, ...] = (1000.0, 7000.0),
    duration_s: float = 5.0,
    samples: int = 20480,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The tables (JSON-ready): per stage at each sensor rate and writer, per stage in teleoperation, per estimator."""
    stages = []
    for rate in rates:
        for writer in ("inline", "process"):
            if progress:
                progress(f"session, sensor at {rate:g} Hz, {writer} writer")
            row = stage_table(rate, duration_s, writer=writer)
            if progress:
                progress(f"the same without the stopwatches, sensor at {rate:g} Hz, {writer} writer")
            bare = stage_table(rate, duration_s, writer=writer, stopwatches=False)
            row["bare"] = {key: bare[key] for key in ("x_real_time", "start_end_ms", "x_real_time_session")}
            row["bare"]["us_per_tick"] = sum(bare["us_per_tick"].values())
            stages.append(row)
    if progress:
        progress("teleoperation session, sensor at 1000 Hz, process writer")
    teleop = stage_table(1000.0, max(duration_s, 8.0), estimator=None, preset="teleop-emulated")
    if progress:
        progress("estimators, µs per sample")
    table = estimator_table(default_estimators(), samples)
    return {
        "stages": stages,
        "teleop": teleop,
        "estimators": {
            label: {str(size): {"median_us": m, "p99_us": p} for size, (m, p) in row.items()}
            for label, row in table.items()
        },
    }
