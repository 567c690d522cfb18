"""The run loop: sensor and kinematics → aligner → estimator → haptic output, all recorded.

Plugins are built once from the config (``build_session``); the loop then
calls plain objects. Each iteration (one device period):

1. read new poses and wrench samples up to now, record them;
2. pair each wrench with its orientation (``core.aligner``), record that;
3. feed good samples (not stale, not saturated, finite) to the estimator, record its estimates;
4. turn the newest estimate into one force command (``sessions.safety``), send and record it;
5. record an event whenever the haptic output switches off or on, or a stage converges.

Ctrl-C ends the loop; the recording is always closed cleanly.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from ...core.aligner import Aligner
from ...core.errors import OutputExistsError
from ...core.plugins import ConfigError, Registry
from ...core.types import STATUS_OK, AlignedSamples, Estimates

from ..config import (
    PLUGIN_TABLES,
    SessionSettings,
    check_tables,
    haptic_settings,
    plugin_options,
    session_settings,
    shadow_tables,
)
from ..recording import Recorder
from .safety import ForceGovernor


@dataclass
class Session:
    """A session's plugins and settings, built and ready to run."""

    config: dict[str, Any]
    settings: SessionSettings
    sensor: Any
    kinematics: Any
    estimator: Any
    estimator_name: str
    haptic: Any
    governor: ForceGovernor
    plugins: dict[str, dict[str, str]]
    resolved_config: dict[str, Any] = field(default_factory=dict)
    ready_force_std: float = 0.05
    shadows: dict[str, Any] = field(default_factory=dict)  # label -> estimator, recorded only
    world: Any = None


@dataclass
class SessionStatus:
    """What the live terminal display shows; updated a few times a second."""

    elapsed_s: float = 0.0
    samples: int = 0
    rate_hz: float = 0.0
    converged_force: bool = False
    converged_torque: bool = False
    contact: bool = False
    haptic_enabled: bool = False
    reason: str = ""
    events: int = 0


@dataclass
class SessionResult:
    """What a finished session reports."""

    path: Path
    samples: int
    poses: int
    duration_s: float
    interrupted: bool
    params: dict[str, list[float]]
    events: list[tuple[int, str, str]] = field(default_factory=list)
    first_converged_force: int | None = None
    first_converged_torque: int | None = None
    contact_samples: int = 0
    haptic_on_s: float = 0.0


def build_session(config: dict[str, Any], registry: Registry | None = None) -> Session:
    """Validate the config and build every plugin it names."""
    registry = registry if registry is not None else Registry()
    check_tables(config)
    settings = session_settings(config)
    safety = haptic_settings(config)
    world = None
    if "world" in config:
        from ...plugins.simworld.physics import SimWorld

        world = SimWorld.from_config(config["world"])
    built: dict[str, Any] = {}
    plugins: dict[str, dict[str, str]] = {}
    resolved = {"session": asdict(settings), "world": config.get("world", {})}
    for table, kind in PLUGIN_TABLES.items():
        name, options = plugin_options(config, table)
        if name is None:
            raise ConfigError(f"{table}.name: missing; the session needs a [{table}] table naming a plugin")
        built[table] = registry.create(kind, name, options, where=table, world=world)
        plugins[table] = {"name": name, "origin": registry.get(kind, name).origin}
        resolved[table] = {"name": name, **registry.resolved_options(kind, name, options)}
    resolved["haptic"].update(asdict(safety))
    if world is None:
        del resolved["world"]
    shadows = {}
    primary = plugin_options(config, "estimator")[0]
    for label, (name, options) in shadow_tables(config).items():
        if label == primary:
            raise ConfigError(f"shadows.{label}: the primary estimator already records on /estimator/{label}; "
                              f"give the shadow another label")
        shadows[label] = registry.create("estimator", name, options, where=f"shadows.{label}", world=world)
        plugins[f"shadow:{label}"] = {"name": name, "origin": registry.get("estimator", name).origin}
        resolved.setdefault("shadows", {})[label] = {
            "name": name, **registry.resolved_options("estimator", name, options)}
    return Session(
        config=config,
        settings=settings,
        sensor=built["sensor"],
        kinematics=built["kinematics"],
        estimator=built["estimator"],
        estimator_name=plugin_options(config, "estimator")[0],
        haptic=built["haptic"],
        # one command per loop iteration: the rate limit works on the loop period
        governor=ForceGovernor(safety, 1.0 / settings.loop_rate_hz),
        plugins=plugins,
        resolved_config=resolved,
        ready_force_std=safety.ready_force_std,
        shadows=shadows,
        world=world,
    )


def session_metadata(session: Session, duration: float, path: Path) -> dict[str, dict[str, Any]]:
    """The MCAP metadata records written at the start of a session."""
    resolved = {**session.resolved_config}
    resolved["session"] = {**resolved["session"], "duration": duration, "out": str(path)}
    return {
        "hapticlab.session": {  # the recorder adds version, git revision and start time
            "config": json.dumps(resolved),
            "plugins": json.dumps(session.plugins),
            "estimator": session.estimator_name,
        },
        "hapticlab.calibration": dict(getattr(session.sensor, "calibration", {}) or {"counts_per_unit": "1"}),
    }


def default_out_path(settings: SessionSettings) -> Path:
    """Where a session records when no output path is given (never an existing file)."""
    if settings.out:
        return Path(settings.out)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    path = Path("recordings") / f"{settings.name}-{stamp}.mcap"
    k = 1
    while path.exists():
        k += 1
        path = Path("recordings") / f"{settings.name}-{stamp}-{k}.mcap"
    return path


class _Recording:
    """Per-sample recording helpers (plain loops over lists: the hot path)."""

    def __init__(self, recorder: Recorder):
        self.rec = recorder

    def poses(self, poses) -> None:
        write = self.rec.write
        for p in poses:
            write("/kinematics/pose", p.t_ns, {
                "quat_BE": p.quat_BE.tolist(),
                "p_BoEo_B": None if p.p_BoEo_B is None else p.p_BoEo_B.tolist(),
                "joints": None if p.joints is None else p.joints.tolist(),
            })

    def wrenches(self, wrenches) -> None:
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


def calibration_path(path: Path) -> Path:
    """Where a session writes its estimator's final state: ``<recording>.calibration.json`` beside the MCAP."""
    return path.with_suffix(".calibration.json")


def _save_estimator_state(estimator: Any, recorder: Recorder, path: Path) -> Path | None:
    """Record the estimator's ``state()`` (when it has one) as the metadata record
    ``hapticlab.estimator_state`` and as ``<recording>.calibration.json`` (a warm start
    for the next session); the JSON file's path, or None."""
    get_state = getattr(estimator, "state", None)
    if get_state is None:
        return None
    state = get_state()
    recorder.add_metadata("hapticlab.estimator_state", state)
    out = calibration_path(path)
    out.write_text(json.dumps(state, indent=1))
    return out


PARAMS_INTERVAL_NS = 100_000_000
STD_CHECK_NS = 10_000_000
"""After the force parameters were first known to ready_force_std, their std is checked again this
often (10 ms): above the bound again (a drifting estimator through a long contact) zeroes the force."""
PAYLOAD_HOLD_NS = 1_000_000_000
"""After an estimator's payload change the haptic force is held at zero this long (1 s): the change
may be a load held by the tool (a grasped object) rather than a new tool, and its release would then
show as a phantom force until the estimator sees the second change."""
"""Parameters and covariance are recorded at 10 Hz (they change slowly; P⁻¹ costs µs)."""


def run_session(
    session: Session,
    out: str | Path | None = None,
    duration: float | None = None,
    on_status: Callable[[SessionStatus], None] | None = None,
    status_interval_s: float = 0.25,
) -> SessionResult:
    """Run a built session until its duration ends (or Ctrl-C) and record it to MCAP."""
    settings = session.settings
    duration = settings.duration if duration is None else duration
    path = Path(out) if out else default_out_path(settings)
    path.parent.mkdir(parents=True, exist_ok=True)
    period_ns = int(round(1e9 / settings.loop_rate_hz))
    duration_ns = int(round(duration * 1e9))
    if settings.stale_timeout > 0:
        stale_timeout_ns = int(round(settings.stale_timeout * 1e9))
    else:  # the first late sample switches the force off
        stale_timeout_ns = int(round(1.5e9 / float(session.sensor.rate_hz))) + period_ns
    if path.exists():
        raise OutputExistsError(f"{path} already exists; choose another --out (recordings are never overwritten)")

    recorder = Recorder(path, metadata=session_metadata(session, duration, path))
    rec = _Recording(recorder)
    estimator_topic = f"/estimator/{session.estimator_name}"
    aligner = Aligner(float(session.kinematics.rate_hz))
    status = SessionStatus()
    events: list[tuple[int, str, str]] = []

    def event(t_ns: int, kind: str, message: str) -> None:
        recorder.event(t_ns, kind, message)
        events.append((t_ns, kind, message))
        status.events += 1

    estimator = session.estimator
    haptic = session.haptic
    samples = poses_seen = 0
    last_sample_ns: int | None = None
    last_estimate: tuple[np.ndarray, np.ndarray] | None = None  # (contact_force_S, R_BE)
    # Algorithm 1 recomputes its flag at every update, so after the first
    # convergence it flickers with noise; the haptics wait for the first
    # convergence ("ready") and the flips are counted, not each made an event.
    converged = [False, False]
    hold_until_ns = 0  # no haptic force before this (a payload change)
    parameters_lost = False  # known once, uncertain again (checked every STD_CHECK_NS)
    next_std_check_ns = 0
    ready = [False, False]
    flips = [0, 0]
    next_params_ns = 0
    contact_samples = 0
    haptic_on_ticks = 0
    haptic_reason = "starting"
    data_reason = ""  # what was wrong with the newest sensor block ("" when it was good)
    parameters_known = False  # force-stage parameter std below ready_force_std (when reported)
    force_std = getattr(estimator, "force_parameter_std", None)
    interrupted = False

    t0_ns = time.monotonic_ns()
    session.sensor.open(t0_ns)
    session.kinematics.open(t0_ns)
    haptic.open()
    event(t0_ns, "session_start", f"session {settings.name!r} started, estimator {session.estimator_name}")
    next_status = time.monotonic()
    tick = 0
    try:
        while True:
            tick += 1
            now_ns = t0_ns + tick * period_ns
            if now_ns - t0_ns > duration_ns:
                break
            if settings.realtime:
                delay = (now_ns - time.monotonic_ns()) * 1e-9
                if delay > 0:
                    time.sleep(delay)

            poses = session.kinematics.read(now_ns)
            if poses:
                aligner.add_poses(poses)
                rec.poses(poses)
                poses_seen += len(poses)
            wrenches = session.sensor.read(now_ns)
            if wrenches:
                rec.wrenches(wrenches)
                samples += len(wrenches)
                last_sample_ns = wrenches[-1].t_ns
                block = aligner.align(wrenches)
                rec.aligned(block)
                good = block.usable
                if good.all():
                    data_reason = ""
                elif block.stale.any():
                    data_reason = "stale kinematics"
                elif (block.status != STATUS_OK).any():
                    data_reason = "sensor saturated or in error"
                else:
                    data_reason = "non-finite sensor reading"
                if good.any():
                    usable = block.subset(good)
                    est = estimator.update_block(usable)
                    for t_ev, kind, msg in getattr(estimator, "drain_events", list)():
                        event(t_ev, kind, msg)
                        if kind == "payload_change":  # the tool's weight just changed: hold, then trust again
                            hold_until_ns = now_ns + PAYLOAD_HOLD_NS
                    with_params = now_ns >= next_params_ns
                    if with_params:
                        next_params_ns = now_ns + PARAMS_INTERVAL_NS
                        rec.estimates(estimator_topic, est, estimator.params(), estimator.cov_diag())
                    else:
                        rec.estimates(estimator_topic, est)
                    for label, shadow in session.shadows.items():  # recorded, never rendered
                        shadow_est = shadow.update_block(usable)
                        rec.estimates(f"/estimator/{label}", shadow_est,
                                      *((shadow.params(), shadow.cov_diag()) if with_params else ()))
                    R_BE = block.R_EB[good][-1].T
                    R_SE = getattr(estimator, "R_SE", None)  # a mount the estimator knows (else S = E)
                    last_estimate = (est.contact_force_S[-1], R_BE if R_SE is None else R_BE @ R_SE.T)
                    status.contact = bool(est.contact[-1])
                    contact_samples += int(np.count_nonzero(est.contact))
                    for stage, flags, label in ((0, est.converged_force, "force"),
                                                (1, est.converged_torque, "torque")):
                        flips[stage] += int(np.count_nonzero(np.diff(flags, prepend=converged[stage])))
                        converged[stage] = bool(flags[-1])
                        if not ready[stage] and flags.any():
                            ready[stage] = True
                            k = int(np.argmax(flags))
                            event(int(est.t_ns[k]), "converged",
                                  f"{session.estimator_name} {label} stage converged")
                    if ready[0] and not parameters_known:
                        parameters_known = force_std is None or \
                            float(np.max(force_std())) <= session.ready_force_std
                        if parameters_known and force_std is not None:
                            event(now_ns, "parameters_known",
                                  f"force parameters known to ±{float(np.max(force_std())):.3g} N (1σ)")
                    elif parameters_known and force_std is not None and now_ns >= next_std_check_ns:
                        # a drifting estimator's uncertainty grows again through a long contact
                        next_std_check_ns = now_ns + STD_CHECK_NS
                        parameters_lost = float(np.max(force_std())) > session.ready_force_std

            # Reasons to hold the force at zero, checked at every tick.
            if last_sample_ns is None or now_ns - last_sample_ns > stale_timeout_ns:
                reason = "no sensor data"
            elif data_reason:
                reason = data_reason
            elif not ready[0]:
                reason = "estimator not converged"
            elif not parameters_known:
                reason = "parameters not yet identified"
            elif parameters_lost:
                reason = "parameters no longer known (uncertainty grew)"
            elif now_ns < hold_until_ns:
                reason = "payload change: tool weight re-identified, holding"
            else:
                reason = ""

            command = session.governor.command(
                now_ns, *(last_estimate if last_estimate else (None, None)), reason=reason
            )
            try:
                haptic.send(command)
                state = haptic.state()
            except Exception as exc:  # a lost device: zero is all we can still ask for
                command = session.governor.command(now_ns, None, None, reason=f"device error: {exc}")
                state = None
            recorder.write("/haptic/command", now_ns, {
                "force_D": command.force_D.tolist(), "enabled": command.enabled,
                "reason": command.reason,
            })
            if state is not None:
                recorder.write("/haptic/state", state.t_ns, {
                    "pose": {"quat_DH": state.quat_DH.tolist(), "p_DoHo_D": state.p_DoHo_D.tolist()},
                    "buttons": int(state.buttons),
                })
            haptic_on_ticks += command.enabled
            if command.reason != haptic_reason:
                if command.enabled:
                    event(now_ns, "haptic_enabled", "haptic force on")
                else:
                    event(now_ns, "haptic_disabled", f"haptic force zeroed: {command.reason}")
                haptic_reason = command.reason

            if on_status is not None and time.monotonic() >= next_status:
                next_status = time.monotonic() + status_interval_s
                elapsed = (now_ns - t0_ns) * 1e-9
                status.elapsed_s = elapsed
                status.samples = samples
                status.rate_hz = samples / elapsed if elapsed > 0 else 0.0
                status.converged_force, status.converged_torque = ready
                status.haptic_enabled = command.enabled
                status.reason = command.reason
                on_status(status)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        end_ns = t0_ns + tick * period_ns
        try:
            haptic.send(session.governor.command(end_ns, None, None, reason="session ended"))
        except Exception:
            pass
        for device in (haptic, session.sensor, session.kinematics):
            try:
                device.close()
            except Exception:
                pass
        params = estimator.params() if samples else {}
        summary = {
            "samples": samples,
            "poses": poses_seen,
            "interrupted": interrupted,
            "params": params,
            "first_converged_force": getattr(estimator, "first_converged_force", None),
            "first_converged_torque": getattr(estimator, "first_converged_torque", None),
            "convergence_flag_flips": {"force": flips[0], "torque": flips[1]},
            "contact_samples": contact_samples,
            "haptic_on_s": haptic_on_ticks * period_ns * 1e-9,
        }
        try:  # never let a failing save cost the recording
            state_path = _save_estimator_state(estimator, recorder, path)
            if state_path is not None:
                summary["estimator_state_path"] = str(state_path)
        except Exception as exc:
            event(end_ns, "estimator_state_not_saved", f"estimator state not saved: {exc}")
        event(end_ns, "session_end", "interrupted (Ctrl-C)" if interrupted else "session finished")
        recorder.close(summary=summary)
    return SessionResult(
        path=path,
        samples=samples,
        poses=poses_seen,
        duration_s=(end_ns - t0_ns) * 1e-9,
        interrupted=interrupted,
        params=params,
        events=events,
        first_converged_force=summary["first_converged_force"],
        first_converged_torque=summary["first_converged_torque"],
        contact_samples=contact_samples,
        haptic_on_s=summary["haptic_on_s"],
    )
