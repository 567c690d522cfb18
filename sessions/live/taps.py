"""The recorder's taps on the live stream: each stage's records as topic messages (the hot path).

The sensor-rate topics (``/sensor/wrench``, ``/aligned/sample``,
``/estimator/<name>``) are written as columnar block messages, the arrays
handed over as they are: the recorder encodes them as CDR, one ``tobytes`` per
field (format 3; ``mcap``'s writer costs the same per message whatever its
size, and JSON formats every float: docs/safety.md, "Overruns"). A block holds what the loop handed
over in :data:`HAND_OVER_NS` (20 ms: 20 ticks at 1 kHz), not one tick: the taps
keep each topic's blocks and write them as one message at the hand-over (an
estimator block that carries ``params`` ends its message, so they still
describe its last sample). Poses (at the kinematics rate), commands and device
states and robot targets (one per tick) and events stay one JSON message each.

The taps only queue their messages; every :data:`HAND_OVER_NS` :meth:`Taps.send`
(called once a tick, after the haptic command has gone out, so none of this is
on the sample-to-command path) encodes the queued JSON messages in the order
written, writes the held blocks and hands the lot to the recorder (with the
writer process: one pipe write per hand-over, not per tick). Encoding 20 ticks'
messages in one pass costs less than a pass per tick (it runs with the
encoder's code and data warm). A killed session loses those 20 ms more, well
inside the second it may lose. Nothing a tap is given may change after it is
given (the loop and the estimators build fresh arrays every tick).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.core.types import (
    AlignedSamples,
    DeviceState,
    Estimates,
    Event,
    HapticCommand,
    PoseSample,
    RobotTarget,
    WrenchBlock,
)
from hapticlab.sessions.recording import Recorder
from hapticlab.sessions.recording.schemas import TF_INTERVAL_NS

HAND_OVER_NS = 20_000_000
"""How long the taps hold the sensor-rate blocks before writing them as one message per topic and handing
the tick's messages to the recorder, ns (20 ms: one encode per topic and one pipe write per hand-over, not
per tick)."""


class _HandOverQueue:
    """The recorder's ``write``/``write_block``/``event``, held until the hand-over (:meth:`send`), in order."""

    def __init__(self, recorder: Recorder):
        self.recorder = recorder
        self.held: list[tuple] = []

    def write(self, topic: str, t_ns: int, message: dict) -> None:
        self.held.append((self.recorder.write, topic, t_ns, message))

    def write_block(self, topic: str, message: dict) -> None:
        self.held.append((self.recorder.write_block, topic, message))

    def event(self, t_ns: int, kind: str, message: str, **data) -> None:
        self.held.append((partial(self.recorder.event, t_ns, kind, message, **data),))

    def send(self) -> None:
        """Encode the held messages in the order written, hand them to the writer."""
        held, self.held = self.held, []
        for method, *args in held:
            method(*args)
        self.recorder.send()


class _Blocks:
    """One block topic's rows held until the hand-over, written as one message (each field's parts concatenated).

    A part is the tuple of a tick's arrays in ``fields``' order (the loop's own arrays, never changed once
    given); ``last`` holds what describes the newest sample (``params``, ``cov_diag``) when a part brought it.
    """

    __slots__ = ("fields", "last", "parts", "topic")

    def __init__(self, topic: str):
        self.topic = topic
        self.parts: list[tuple[np.ndarray, ...]] = []
        self.fields: tuple[str, ...] = ()  # the fields of the held parts
        self.last: dict[str, object] = {}

    def write(self, rec: _HandOverQueue) -> None:
        parts, self.parts = self.parts, []
        if not parts:
            return
        if len(parts) == 1:
            message: dict[str, object] = dict(zip(self.fields, parts[0]))
        else:
            message = {k: np.concatenate(column) for k, column in zip(self.fields, zip(*parts))}
        if self.last:
            message.update(self.last)
            self.last = {}
        rec.write_block(self.topic, message)


ALIGNED_FIELDS = ("t_ns", "force_S", "torque_S", "seq", "status", "stale")
ALIGNED_FIELDS_WITH_QUAT = (*ALIGNED_FIELDS, "quat_BE")
ESTIMATE_FIELDS = ("t_ns", "contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque")


class Taps:
    """Writes poses, wrenches, aligned samples, estimates, commands, device states and events.

    Each tap queues its message; :meth:`send` records what is queued at each hand-over (call it once per tick,
    after the command, with the tick's time; and once without one before the recorder is closed: it writes
    what is held).
    """

    def __init__(self, recorder: Recorder):
        self.rec = _HandOverQueue(recorder)
        self.clock_offset_ns = int(getattr(recorder, "clock_offset_ns", 0))  # /tf's stamps: Unix time, as log times
        self._wrenches: list[WrenchBlock] = []  # the raw readings held until the hand-over
        self._blocks: dict[str, _Blocks] = {}
        self._hand_over_ns: int | None = None  # the next hand-over (set by the first send)
        self._target_R: np.ndarray | None = None  # the last robot target's orientation and its quaternion
        self._target_quat: list[float] = []
        self._next_tf_ns = {"flange": 0, "target": 0}

    def poses(self, poses: list[PoseSample], now_ns: int) -> None:
        """The poses read at the tick ``now_ns``, each with its age then (``age_ns``: the kinematics' delay)."""
        write = self.rec.write
        for p in poses:
            write(
                "/kinematics/pose",
                p.t_ns,
                {
                    "quat_BE": p.quat_BE.tolist(),
                    "p_BoEo_B": None if p.p_BoEo_B is None else p.p_BoEo_B.tolist(),
                    "joints": None if p.joints is None else p.joints.tolist(),
                    "wrench_B": None if p.wrench_B is None else p.wrench_B.tolist(),
                    "age_ns": now_ns - p.t_ns,
                },
            )
        last = poses[-1]
        if last.t_ns >= self._next_tf_ns["flange"] and last.p_BoEo_B is not None:
            self.transform(last.t_ns, "flange", last.quat_BE.tolist(), last.p_BoEo_B.tolist())

    def transform(self, t_ns: int, child: str, quat_wxyz: list[float], p: list[float]) -> None:
        """``/tf``: the frame ``child`` in the robot base (Foxglove's FrameTransform), at most every 20 ms."""
        self._next_tf_ns[child] = t_ns + TF_INTERVAL_NS
        w, x, y, z = quat_wxyz
        stamp = t_ns + self.clock_offset_ns
        self.rec.write(
            "/tf",
            t_ns,
            {
                "timestamp": {"sec": stamp // 1_000_000_000, "nsec": stamp % 1_000_000_000},
                "parent_frame_id": "base",
                "child_frame_id": child,
                "translation": {"x": p[0], "y": p[1], "z": p[2]},
                "rotation": {"x": x, "y": y, "z": z, "w": w},
            },
        )

    def wrenches(self, wrenches: WrenchBlock) -> None:
        self._wrenches.append(wrenches)

    def _write_wrenches(self) -> None:
        blocks, self._wrenches = self._wrenches, []
        if blocks:
            one = WrenchBlock.concatenate(blocks)
            self.rec.write_block(
                "/sensor/wrench",
                {
                    "t_ns": one.t_ns,
                    "force_S": one.force_S,
                    "torque_S": one.torque_S,
                    "seq": one.seq,
                    "status": one.status,
                },
            )

    def _hold(self, topic: str, fields: tuple[str, ...], values: tuple[np.ndarray, ...], **last) -> None:
        """Hold a tick's ``values`` (one array per name in ``fields``) with the topic's others; ``last``
        (``params``/``cov_diag``, when given) ends the held messages (they describe its last sample), and so
        does a field that comes or goes. What is held is always written whole and in the loop's order (the
        wrenches, the aligned samples, then the estimators': a reader finds an estimate's raw reading
        written before it)."""
        blocks = self._blocks.get(topic)
        if blocks is None:
            blocks = self._blocks[topic] = _Blocks(topic)
        if blocks.parts and fields is not blocks.fields:  # (this module's field tuples) one message held, this another
            self._write_held()
        blocks.fields = fields
        blocks.parts.append(values)
        if last:
            blocks.last = last
            self._write_held()

    def _write_held(self) -> None:
        self._write_wrenches()
        for blocks in self._blocks.values():  # in the order the loop first handed them over
            blocks.write(self.rec)

    def aligned(self, block: AlignedSamples) -> None:
        if not len(block.t_ns):
            return
        values = (block.t_ns, block.force_S, block.torque_S, block.seq, block.status, block.stale)
        if block.quat_BE is None:
            self._hold("/aligned/sample", ALIGNED_FIELDS, values)
        else:
            self._hold("/aligned/sample", ALIGNED_FIELDS_WITH_QUAT, (*values, block.quat_BE))

    def estimates(self, topic: str, est: Estimates, params=None, cov_diag=None) -> None:
        """One block message; ``params``/``cov_diag`` (when given) describe its last sample."""
        if not len(est):
            return
        values = (
            est.t_ns,
            est.contact_force_S,
            est.contact_torque_S,
            est.contact,
            est.converged_force,
            est.converged_torque,
        )
        if params is None and cov_diag is None:
            self._hold(topic, ESTIMATE_FIELDS, values)
        else:
            self._hold(
                topic,
                ESTIMATE_FIELDS,
                values,
                **{k: v for k, v in (("params", params), ("cov_diag", cov_diag)) if v is not None},
            )

    def command(self, command: HapticCommand, contact_force_N: float | None = None, contact: bool = False) -> None:
        """``/haptic/command``, with the tool–tissue force it was made from: the primary estimator's newest
        ‖contact force‖ (N; None before its first estimate) and whether it judged that a contact."""
        self.rec.write(
            "/haptic/command",
            command.t_ns,
            {
                "force_D": command.force_D.tolist(),
                "enabled": command.enabled,
                "reason": command.reason,
                "source_t_ns": command.source_t_ns,
                "contact_force_N": contact_force_N,
                "contact": contact,
            },
        )

    def device_state(self, state: DeviceState) -> None:
        self.rec.write(
            "/haptic/state",
            state.t_ns,
            {
                "pose": {"quat_DH": state.quat_DH.tolist(), "p_DoHo_D": state.p_DoHo_D.tolist()},
                "buttons": int(state.buttons),
                "v_DHo_D": None if state.v_DHo_D is None else state.v_DHo_D.tolist(),
            },
        )

    def passivity(self, t_ns: int, energy_J: float, damping: float) -> None:
        """``/haptic/passivity``: the port's energy and the damping its controller added at the tick ``t_ns``."""
        self.rec.write("/haptic/passivity", t_ns, {"energy_J": energy_J, "damping": damping})

    def robot_target(self, target: RobotTarget) -> None:
        if target.R_BE is not self._target_R:  # teleoperation holds one orientation object while it holds it
            self._target_R, self._target_quat = target.R_BE, quat_wxyz_from_matrix(target.R_BE).tolist()
        p = target.p_BoEo_B.tolist()
        self.rec.write(
            "/robot/target",
            target.t_ns,
            {"pose": {"quat_BE": self._target_quat, "p_BoEo_B": p}, "mode": target.mode, "reason": target.reason},
        )
        if target.t_ns >= self._next_tf_ns["target"]:
            self.transform(target.t_ns, "target", self._target_quat, p)

    def event(self, event: Event) -> None:
        self.rec.event(event.t_ns, event.kind, event.message, **event.data)

    def send(self, now_ns: int | None = None) -> None:
        """At the hand-over (every :data:`HAND_OVER_NS` of ``now_ns``, and always without it: the session's end)
        encode the queued messages in order, write the held blocks and hand everything to the recorder (the
        writer process: one pipe write); between hand-overs, nothing."""
        if now_ns is not None:
            if self._hand_over_ns is None:
                self._hand_over_ns = now_ns + HAND_OVER_NS
            elif now_ns < self._hand_over_ns:
                return
            else:
                self._hand_over_ns = now_ns + HAND_OVER_NS
        self._write_held()
        self.rec.send()
