"""The recorder's taps on the live stream: each stage's records as topic messages (the hot path).

Plain loops over lists: converting a block's arrays to lists once and writing
one JSON message per sample is the cheapest way through ``json`` and ``mcap``.
"""

from __future__ import annotations

from ...core.types import AlignedSamples, DeviceState, Estimates, Event, HapticCommand, PoseSample, WrenchSample
from ..recording import Recorder


class Taps:
    """Writes poses, wrenches, aligned samples, estimates, commands, device states and events."""

    def __init__(self, recorder: Recorder):
        self.rec = recorder

    def poses(self, poses: list[PoseSample]) -> None:
        write = self.rec.write
        for p in poses:
            write("/kinematics/pose", p.t_ns, {
                "quat_BE": p.quat_BE.tolist(),
                "p_BoEo_B": None if p.p_BoEo_B is None else p.p_BoEo_B.tolist(),
                "joints": None if p.joints is None else p.joints.tolist(),
            })

    def wrenches(self, wrenches: list[WrenchSample]) -> None:
        write = self.rec.write
        for w in wrenches:
            write("/sensor/wrench", w.t_ns, {
                "force_S": w.force_S.tolist(), "torque_S": w.torque_S.tolist(),
                "seq": int(w.seq), "status": int(w.status),
            })

    def aligned(self, block: AlignedSamples) -> None:
        write = self.rec.write
        quat_BE, seq, status, stale = (block.quat_BE.tolist(), block.seq.tolist(),
                                       block.status.tolist(), block.stale.tolist())
        force, torque = block.force_S.tolist(), block.torque_S.tolist()
        for i, t in enumerate(block.t_ns.tolist()):
            write("/aligned/sample", t, {
                "force_S": force[i], "torque_S": torque[i], "quat_BE": quat_BE[i],
                "seq": seq[i], "status": status[i], "stale": stale[i],
            })

    def estimates(self, topic: str, est: Estimates, params=None, cov_diag=None) -> None:
        """One message per sample; ``params``/``cov_diag`` (when given) ride on the last one."""
        write = self.rec.write
        n = len(est)
        f, tau = est.contact_force_S.tolist(), est.contact_torque_S.tolist()
        contact, cf, ct = est.contact.tolist(), est.converged_force.tolist(), est.converged_torque.tolist()
        for i, t in enumerate(est.t_ns.tolist()):
            last = i == n - 1
            write(topic, t, {
                "contact_force_S": f[i], "contact_torque_S": tau[i], "contact": contact[i],
                "converged_force": cf[i], "converged_torque": ct[i],
                "params": params if last else None,
                "cov_diag": cov_diag if last else None,
            })

    def command(self, command: HapticCommand) -> None:
        self.rec.write("/haptic/command", command.t_ns, {
            "force_D": command.force_D.tolist(), "enabled": command.enabled, "reason": command.reason,
        })

    def device_state(self, state: DeviceState) -> None:
        self.rec.write("/haptic/state", state.t_ns, {
            "pose": {"quat_DH": state.quat_DH.tolist(), "p_DoHo_D": state.p_DoHo_D.tolist()},
            "buttons": int(state.buttons),
        })

    def event(self, event: Event) -> None:
        self.rec.event(event.t_ns, event.kind, event.message, **event.data)
