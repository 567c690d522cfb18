"""Building a session: validate the config, build every plugin once, find their capabilities.

Everything the loop needs is decided here, before the first sample: which
plugins, with which options, which optional capabilities each has
(``core.host.interfaces``), where the recording goes. The loop then only calls
plain objects. The host knows nothing special about any plugin: a shared
object such as the simulated world is a *context* (``register_contexts``),
built from its own config table and handed to the factories that ask for it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from hapticlab.core.errors import ConfigError, OutputExistsError, UserError
from hapticlab.core.host.interfaces import (
    CountsConvergence,
    EmitsEvents,
    Estimator,
    HapticOutput,
    HasCalibration,
    HasLatency,
    HoldsOutOutliers,
    KinematicsSource,
    KnowsMount,
    MeasuresWrench,
    Reidentifies,
    ReidentifiesWeight,
    ReportsCovariance,
    ReportsParameterStd,
    ReportsParams,
    SavesState,
    SensorSource,
    ServosCartesian,
)
from hapticlab.core.host.options import OptionError, listen_address
from hapticlab.core.host.registry import Registry
from hapticlab.sessions.config import PLUGIN_TABLES, check_tables, plugin_options, shadow_tables
from hapticlab.sessions.live.gate import HapticGate
from hapticlab.sessions.live.safety import ForceGovernor
from hapticlab.sessions.output import check_writable
from hapticlab.sessions.settings import (
    HapticSettings,
    SessionSettings,
    TeleopSettings,
    haptic_settings,
    session_settings,
    teleop_settings,
)
from hapticlab.sessions.tasks import prepare as prepare_task
from hapticlab.sessions.tools import ToolPlan
from hapticlab.sessions.tools import prepare as prepare_tool

INTERFACES = {"sensor": SensorSource, "kinematics": KinematicsSource, "estimator": Estimator, "haptic": HapticOutput}
"""The interface each plugin table's object must have (checked at build time)."""
REQUIRED = tuple(INTERFACES.values())


@dataclass
class EstimatorSlot:
    """One estimator of the session and what it can do, found once at build time.

    Attributes:
        label: the name it records under (``/estimator/<label>``).
        estimator: the object.
        events: the same object when it emits events, else None.
        parameter_std: the same object when it reports its force parameters' std, else None.
        mount: the same object when it knows the sensor's mount, else None.
        counts: the same object when it counts its first convergence, else None.
        saves: the same object when its state starts the next session, else None.
        reidentifies: the same object when it can re-identify its bias on request, else None.
        reidentifies_weight: the same object when it can re-identify the tool's weight on request, else None.
        holds_out: the same object when it holds samples out of its update without calling them a contact.
        reports_params: the same object when it reports its parameters (``params()``), else None.
        reports_cov: the same object when it reports its covariance diagonal (``cov_diag()``), else None.
    """

    label: str
    estimator: Estimator
    events: EmitsEvents | None = None
    parameter_std: ReportsParameterStd | None = None
    mount: KnowsMount | None = None
    counts: CountsConvergence | None = None
    saves: SavesState | None = None
    reidentifies: Reidentifies | None = None
    holds_out: HoldsOutOutliers | None = None
    reports_params: ReportsParams | None = None
    reports_cov: ReportsCovariance | None = None
    reidentifies_weight: ReidentifiesWeight | None = None

    @classmethod
    def of(cls, label: str, estimator: Any) -> EstimatorSlot:
        """The slot for ``estimator``, its capabilities checked once."""

        def has(capability):
            return estimator if isinstance(estimator, capability) else None

        return cls(
            label,
            estimator,
            has(EmitsEvents),
            has(ReportsParameterStd),
            has(KnowsMount),
            has(CountsConvergence),
            has(SavesState),
            has(Reidentifies),
            has(HoldsOutOutliers),
            has(ReportsParams),
            has(ReportsCovariance),
            has(ReidentifiesWeight),
        )

    @property
    def topic(self) -> str:
        return f"/estimator/{self.label}"

    def params(self) -> dict[str, list[float]] | None:
        """The estimator's parameters, or None when it reports none."""
        return None if self.reports_params is None else self.reports_params.params()

    def cov_diag(self) -> list[float] | None:
        """The estimator's covariance diagonal, or None when it reports none."""
        return None if self.reports_cov is None else self.reports_cov.cov_diag()


@dataclass
class Session:
    """A session's plugins and settings, built and ready to run."""

    config: dict[str, Any]
    settings: SessionSettings
    haptic_settings: HapticSettings
    sensor: SensorSource
    kinematics: KinematicsSource
    primary: EstimatorSlot
    haptic: HapticOutput
    plugins: dict[str, dict[str, str]]
    resolved_config: dict[str, Any] = field(default_factory=dict)
    shadows: list[EstimatorSlot] = field(default_factory=list)  # recorded, never rendered
    contexts: dict[str, Any] = field(default_factory=dict)  # e.g. {"world": SimWorld}
    device_events: list[tuple[str, EmitsEvents]] = field(default_factory=list)  # (label, device)
    teleop_settings: TeleopSettings = field(default_factory=TeleopSettings)
    robot: ServosCartesian | None = None  # the kinematics, when teleoperation drives it
    tool: ToolPlan = field(default_factory=ToolPlan)  # the tool on the sensor ([tool]), and what came of the library

    @property
    def estimator(self) -> Estimator:
        """The estimator that drives the haptics."""
        return self.primary.estimator

    @property
    def estimator_name(self) -> str:
        return self.primary.label

    @property
    def estimators(self) -> list[EstimatorSlot]:
        """The primary then the shadows."""
        return [self.primary, *self.shadows]

    def governor(self) -> ForceGovernor:
        """A fresh force governor: one command per loop period, so the rate limit works on that period."""
        return ForceGovernor(self.haptic_settings, 1.0 / self.settings.loop_rate_hz)

    def gate(self) -> HapticGate:
        """A fresh haptic gate for the primary estimator, with the session's timeouts and limits."""
        settings = self.settings
        sensor_latency_s = self.sensor.latency_s if isinstance(self.sensor, HasLatency) else 0.0
        stale_ns = stale_timeout_ns(
            settings.stale_timeout, float(self.sensor.rate_hz), settings.loop_rate_hz, sensor_latency_s
        )
        return HapticGate(
            self.estimator_name,
            self.haptic_settings.ready_force_std,
            self.primary.parameter_std,
            self.primary.reidentifies,
            stale_ns,
            round(settings.frozen_pose_timeout * 1e9),
            settings.max_turn_rate,
            settings.max_speed,
            reports_params=self.primary.reports_params is not None,
            reidentifies_weight=self.primary.reidentifies_weight,
            wrench_accuracy_N=self.kinematics.wrench_accuracy_N if isinstance(self.kinematics, MeasuresWrench) else 0.0,
            tool_mass=self.haptic_settings.tool_mass,
            tool_axis_S=self.haptic_settings.tool_axis,
        )


def stale_timeout_ns(
    stale_timeout: float, sensor_rate_hz: float, loop_rate_hz: float, sensor_latency_s: float = 0.0
) -> int:
    """The age of the newest sensor sample at which the force is zeroed, ns: ``session.stale_timeout`` s, or
    when 0 (automatic) 1.5 sensor periods plus the sensor's latency plus one loop period."""
    period_ns = round(1e9 / loop_rate_hz)
    if stale_timeout > 0:
        return round(stale_timeout * 1e9)
    return round((1.5 / sensor_rate_hz + sensor_latency_s) * 1e9) + period_ns


def build_session(config: dict[str, Any], registry: Registry | None = None) -> Session:
    """Validate the config and build every plugin it names (ConfigError naming the key if anything is wrong)."""
    registry = registry if registry is not None else Registry()
    context_names = registry.names("context")
    check_tables(config, extra_tables=context_names)
    config = prepare_task(config)  # (in a simulated world: the task's inclusion, the simulated hand's script)
    estimator_name = plugin_options(config, "estimator")[0]
    takes_warm_start = estimator_name in registry.names("estimator") and "warm_start" in registry.resolved_options(
        "estimator", estimator_name, {}
    )  # (an unknown name: refused below, with the names)
    config, tool = prepare_tool(config, takes_warm_start)  # (a known tool: its state and mass)
    settings = session_settings(config)
    safety = haptic_settings(config)
    contexts = {
        name: registry.create("context", name, {"table": config[name]}, where=name)
        for name in context_names
        if name in config
    }
    built: dict[str, Any] = {}
    plugins: dict[str, dict[str, str]] = {}
    resolved: dict[str, Any] = {"session": asdict(settings)}
    resolved.update({name: config[name] for name in contexts})
    for table, kind in PLUGIN_TABLES.items():
        name, options = plugin_options(config, table)
        if name is None:
            raise ConfigError(f"{table}.name: missing; the session needs a [{table}] table naming a plugin")
        built[table] = _create(registry, kind, name, options, table, contexts)
        plugins[table] = {"name": name, "origin": registry.get(kind, name).origin}
        resolved[table] = {"name": name, **registry.resolved_options(kind, name, options)}
    resolved["haptic"].update(asdict(safety))
    primary = plugin_options(config, "estimator")[0]
    shadows = []
    for label, (name, options) in shadow_tables(config).items():
        if label == primary:
            raise ConfigError(
                f"shadows.{label}: the primary estimator already records on /estimator/{label}; "
                f"give the shadow another label"
            )
        where = f"shadows.{label}"
        shadows.append(EstimatorSlot.of(label, _create(registry, "estimator", name, options, where, contexts)))
        plugins[f"shadow:{label}"] = {"name": name, "origin": registry.get("estimator", name).origin}
        resolved.setdefault("shadows", {})[label] = {
            "name": name,
            **registry.resolved_options("estimator", name, options),
        }
    device_events = [
        (table, built[table]) for table in ("sensor", "kinematics", "haptic") if isinstance(built[table], EmitsEvents)
    ]
    teleop = teleop_settings(config)
    resolved["teleop"] = asdict(teleop)
    if "task" in config:
        resolved["task"] = config["task"]
    if tool.name:
        resolved["tool"] = tool.resolved()
    robot = None
    if teleop.enabled:
        robot = built["kinematics"]
        if not isinstance(robot, ServosCartesian):
            name = plugins["kinematics"]["name"]
            hint = (
                '; the simulated robot follows targets with [world.motion] script = "servo"'
                if name == "sim"
                else "; ur_rtde follows them with kinematics.follow = true"
                if name == "ur_rtde"
                else ""
            )
            raise ConfigError(f"teleop.enabled: kinematics {name!r} cannot follow a target (it has no servo_cp){hint}")
    if teleop.delay_s > 0 and plugins["haptic"]["name"] != "sim":  # (a delayed zero reaches a real hand late)
        raise ConfigError(
            f'teleop.delay_s: a delayed link is simulated with the simulated master only (haptic.name = "sim"), '
            f"got {plugins['haptic']['name']!r}: the gate's zero would reach a real hand {teleop.delay_s:g} s late"
        )
    return Session(
        config=config,
        settings=settings,
        haptic_settings=safety,
        sensor=built["sensor"],
        kinematics=built["kinematics"],
        primary=EstimatorSlot.of(primary, built["estimator"]),
        haptic=built["haptic"],
        plugins=plugins,
        resolved_config=resolved,
        tool=tool,
        shadows=shadows,
        contexts=contexts,
        device_events=device_events,
        teleop_settings=teleop,
        robot=robot,
    )


def _create(
    registry: Registry, kind: str, name: str, options: dict[str, Any], where: str, contexts: dict[str, Any]
) -> Any:
    """Build one plugin and check it has the interface its table needs."""
    obj = registry.create(kind, name, options, where=where, **contexts)
    interface = INTERFACES["estimator" if where.startswith("shadows.") else where]
    if not isinstance(obj, interface):
        missing = [m for m in _members(interface) if not hasattr(obj, m)]
        raise ConfigError(
            f"{where}.name: {kind} {name!r} ({registry.get(kind, name).origin}) is not a "
            f"{interface.__name__}: it lacks {', '.join(missing)}"
        )
    return obj


def _members(protocol: type) -> list[str]:
    return sorted(
        set(getattr(protocol, "__annotations__", {}))
        | {k for k, v in vars(protocol).items() if callable(v) and not k.startswith("_")}
    )


def session_metadata(session: Session, duration: float, path: Path) -> dict[str, dict[str, Any]]:
    """The MCAP metadata records written at the start of a session."""
    resolved = {**session.resolved_config}
    resolved["session"] = {**resolved["session"], "duration": duration, "out": str(path)}
    calibration = session.sensor.calibration if isinstance(session.sensor, HasCalibration) else {}
    return {
        "hapticlab.session": {  # the recorder adds version, git revision and start time
            "config": json.dumps(resolved),
            "plugins": json.dumps(session.plugins),
            "estimator": session.estimator_name,
        },
        "hapticlab.calibration": dict(calibration or {"counts_per_unit": "1"}),
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


def calibration_path(path: Path) -> Path:
    """Where a session writes its estimator's final state: ``<recording>.calibration.json`` beside the MCAP."""
    return Path(path).with_suffix(".calibration.json")


def refuse_existing_outputs(path: Path, saves_state: bool) -> None:
    """OutputExistsError when the recording ``path`` exists (a symlink, even to nowhere, too), or
    (``saves_state``: the primary saves its state) its :func:`calibration_path` does: a session never
    overwrites what an earlier one wrote. UserError when it is a folder, or its nearest existing folder is
    a file or cannot be written in (the missing ones are made when the session starts)."""
    if path.is_dir():
        raise UserError(f"--out {path}: is a folder; give a recording's file name (.mcap)")
    if path.exists() or path.is_symlink():
        raise OutputExistsError(f"{path} already exists; choose another --out (recordings are never overwritten)")
    existing = next(p for p in path.parents if p.exists() or p.is_symlink())  # "." or "/" at last
    if not existing.is_dir():
        raise UserError(f"--out {path}: {existing} is not a folder")
    check_writable(existing, f"--out {path}")
    if saves_state and calibration_path(path).exists():
        raise OutputExistsError(
            f"{calibration_path(path)} already exists (the estimator's state of an earlier session); "
            "choose another --out (it is never overwritten)"
        )


def check_live_address(address: str, recording_writer: str = "process", allow_network: bool = False) -> None:
    """A ``--live`` address: ``HOST:PORT`` with a port in 0..65535, a loopback host unless ``allow_network``
    (the live view serves every topic, ``/haptic/command`` included, with no authentication), and a session
    whose recording has a writer process to serve it (ConfigError naming what is wrong otherwise)."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise ConfigError(f"--live {address!r}: expected HOST:PORT, e.g. 127.0.0.1:8765")
    try:
        listen_address(
            "--live",
            host,
            allow_network=allow_network,
            exposes="every topic of the session, /haptic/command included, with no authentication,",
        )
    except OptionError as exc:
        raise exc.under("") from None
    if recording_writer != "process":
        raise ConfigError(
            "--live: the live view is served by the recording's writer process; "
            'drop session.recording_writer = "inline"'
        )
