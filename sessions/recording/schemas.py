"""The recording's contract: MCAP magic, topics and their JSON schemas, metadata record names.

Topics (see DESIGN.md "Recording (MCAP)"; SI units, frames in the field
names): ``/sensor/wrench``, ``/kinematics/pose``, ``/aligned/sample``,
``/estimator/<name>`` (one channel per estimator, one shared schema),
``/haptic/command``, ``/haptic/state``, ``/robot/target`` and ``/haptic/passivity`` (teleoperation), ``/tf``
(Foxglove's ``foxglove.FrameTransform``, for its 3D panel), ``/events``. Any other topic is
refused with a ``ValueError``. :data:`SCHEMAS` holds the JSON schemas.

Three layouts (:data:`FORMAT_VERSION`): format 1 wrote one message per sample
on every topic; format 2 writes the sensor-rate topics (:data:`BLOCK_TOPICS`:
``/sensor/wrench``, ``/aligned/sample``, ``/estimator/<name>``) as one message
per block of samples, columnar (``{"t_ns": [...], "force_S": [[fx, fy, fz],
...], ...}``: element ``i`` of every array is sample ``i``), on channels whose
schema is the block schema (:func:`block_schema_for_topic`, titles ending in
``Block``, listed in :data:`BLOCK_SCHEMA_TITLES`). Format 3 writes the same
blocks in binary: ROS 2 message definitions (schema encoding ``ros2msg``,
Foxglove reads them natively) with CDR messages (message encoding ``cdr``), one
flat array per field (:mod:`.cdr_layouts`). The reader tells the layouts apart
by each channel's schema and message encoding and reads all three.
"""

from __future__ import annotations

import re
from typing import Any

MCAP_MAGIC = b"\x89MCAP0\r\n"
ESTIMATOR_TOPIC_PREFIX = "/estimator/"
_ESTIMATOR_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*\Z")
_JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

#: The recording's layout, ``format_version`` in the ``hapticlab.session`` metadata (absent = 1):
#: 1 one message per sample on every topic; 2 the sensor-rate topics may be in blocks
#: (:data:`BLOCK_TOPICS`; JSON); 3 those blocks are CDR (:data:`.cdr_layouts.CDR_BLOCKS`; a live session writes
#: them so). The reader goes by each channel's schema and message encoding.
FORMAT_VERSION = 3

SESSION_METADATA = "hapticlab.session"
CALIBRATION_METADATA = "hapticlab.calibration"
SUMMARY_METADATA = "hapticlab.summary"
RECOVERED_METADATA = "hapticlab.recovered"

# --------------------------------------------------------------------------
# JSON schemas (draft 2020-12), one per topic; estimator channels share one.
# --------------------------------------------------------------------------

_NUM = {"type": ["number", "null"]}  # null marks a non-finite value (NaN/inf)


def _vec(n: int, description: str) -> dict[str, Any]:
    return {"type": "array", "items": _NUM, "minItems": n, "maxItems": n, "description": description}


def _quat(description: str) -> dict[str, Any]:
    return _vec(4, description + " Unit quaternion [w, x, y, z].")


def _schema(title: str, description: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {
        "$schema": _JSON_SCHEMA_DIALECT,
        "title": title,
        "description": description + " Non-finite numbers are recorded as null.",
        "type": "object",
        "properties": properties,
        "required": required,
    }


_WRENCH_SCHEMA = _schema(
    "hapticlab.SensorWrench",
    "One raw reading of the six-axis force/torque sensor.",
    {
        "force_S": _vec(3, "Raw force in the sensor frame S, N."),
        "torque_S": _vec(3, "Raw torque in S about the sensor origin, N·m."),
        "seq": {"type": "integer", "description": "Device sequence number (NetFT RDT sequence or a counter)."},
        "status": {"type": "integer", "description": "Device status bits; 0 = good, 1 = saturated, 2 = device error."},
    },
    ["force_S", "torque_S", "seq", "status"],
)

_POSE_SCHEMA = _schema(
    "hapticlab.KinematicsPose",
    "One forward-kinematics reading of the robot end (flange) frame E in the robot base frame B.",
    {
        "quat_BE": _quat("Orientation R_BE of the end frame E in the base frame B."),
        "p_BoEo_B": {
            **_vec(3, "Position of E's origin from B's origin, expressed in B, m; null when unknown."),
            "type": ["array", "null"],
        },
        "joints": {
            "type": ["array", "null"],
            "items": _NUM,
            "description": "Joint positions, rad (m for prismatic joints); null when unknown.",
        },
        "wrench_B": {
            "type": ["array", "null"],
            "items": _NUM,
            "description": "The robot's own measure of the contact wrench on its tool (CRTK measured_cf; a UR's "
            "actual_TCP_force), expressed in B: force, N, then moment about the TCP, N·m; null when it gives none.",
        },
        "age_ns": {
            "type": "integer",
            "description": "How old the pose was when the loop read it: the "
            "session clock at that tick minus the pose's time, ns (a networked arm's delay).",
        },
    },
    ["quat_BE"],
)

_ALIGNED_SCHEMA = _schema(
    "hapticlab.AlignedSample",
    "A wrench sample paired with the robot orientation interpolated at the sample's own time.",
    {
        "force_S": _vec(3, "Raw force in the sensor frame S, N."),
        "torque_S": _vec(3, "Raw torque in S, N·m."),
        "quat_BE": _quat("Orientation R_BE of E in B at the sample's time (the estimator uses R_EB = R_BEᵀ)."),
        "seq": {"type": "integer", "description": "Sensor sequence number of the sample."},
        "status": {"type": "integer", "description": "Sensor status bits; 0 = good."},
        "stale": {
            "type": "boolean",
            "description": ("True when the orientation was held longer than one kinematics period past the last pose."),
        },
    },
    ["force_S", "torque_S", "quat_BE", "seq", "status", "stale"],
)

_ESTIMATOR_SCHEMA = _schema(
    "hapticlab.EstimatorEstimate",
    "One estimator's output for one sample (channel /estimator/<name>).",
    {
        "contact_force_S": _vec(3, "Estimated tool-tissue contact force in the sensor frame S, N."),
        "contact_torque_S": _vec(3, "Estimated contact torque in S, N·m."),
        "contact": {"type": "boolean", "description": "The estimator judged the sample to be in contact."},
        "converged_force": {"type": "boolean", "description": "The force stage has converged."},
        "converged_torque": {"type": "boolean", "description": "The torque stage has converged."},
        "params": {
            "type": "object",
            "additionalProperties": {"type": "array", "items": _NUM},
            "description": (
                "Current parameter estimates, name -> list of floats, SI units and frames in the names "
                "(gravity_force_B N, bias_force_S N, cog_S m, bias_torque_S N·m, ...)."
            ),
        },
        "cov_diag": {
            "type": "array",
            "items": _NUM,
            "description": "Diagonal of the parameter covariance, in the squared units of the parameters.",
        },
    },
    ["contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque"],
)

_COMMAND_SCHEMA = _schema(
    "hapticlab.HapticCommand",
    "Force command sent to the haptic master device.",
    {
        "force_D": _vec(3, "Force on the handle in the device base frame D, N."),
        "enabled": {"type": "boolean", "description": "False when the output is held at zero for safety."},
        "reason": {"type": "string", "description": "Why the output is disabled; present when enabled is false."},
        "source_t_ns": {
            "type": ["integer", "null"],
            "description": "Stamp of the newest sensor sample behind the force, ns (null: zero command).",
        },
        "contact_force_N": {
            "type": ["number", "null"],
            "description": "The tool-tissue force the command was made from: the primary estimator's newest "
            "|contact force|, N (null: no estimate yet).",
        },
        "contact": {"type": "boolean", "description": "Whether the primary estimator judged that sample a contact."},
    },
    ["force_D", "enabled"],
)

_STATE_SCHEMA = _schema(
    "hapticlab.HapticState",
    "State reported by the haptic master device.",
    {
        "pose": {
            "type": "object",
            "description": "Pose of the handle frame H in the device base frame D.",
            "properties": {
                "quat_DH": _quat("Orientation R_DH of the handle H in the device base D."),
                "p_DoHo_D": _vec(3, "Position of H's origin from D's origin, expressed in D, m."),
            },
            "required": ["quat_DH", "p_DoHo_D"],
        },
        "buttons": {"type": "integer", "description": "Bit mask of pressed buttons."},
        "v_DHo_D": {
            "type": ["array", "null"],
            "items": {"type": ["number", "null"]},
            "minItems": 3,
            "maxItems": 3,
            "description": "Velocity of H's origin in D, expressed in D, m/s (null: not reported).",
        },
    },
    ["pose", "buttons"],
)

_TARGET_SCHEMA = _schema(
    "hapticlab.RobotTarget",
    "Where teleoperation sends the robot's flange E (CRTK servo_cp), one per loop tick.",
    {
        "pose": {
            "type": "object",
            "description": "Target pose of the flange E in the robot base B.",
            "properties": {
                "quat_BE": _quat("Target orientation R_BE of E in B."),
                "p_BoEo_B": _vec(3, "Target position of E's origin from B's origin, expressed in B, m."),
            },
            "required": ["quat_BE", "p_BoEo_B"],
        },
        "mode": {"type": "string", "description": "calibrating, following or holding."},
        "reason": {"type": "string", "description": "Why the target is holding (empty otherwise)."},
    },
    ["pose", "mode"],
)

_PASSIVITY_SCHEMA = _schema(
    "hapticlab.HapticPassivity",
    "The haptic port's passivity observer and controller (teleoperation), one per loop tick.",
    {
        "energy_J": {
            "type": "number",
            "description": "Energy the device has put into the hand since the session began, J: sum of force_D . "
            "v_DHo_D dt (<= 0 while the port is passive).",
        },
        "damping": {"type": "number", "description": "Damping the controller added at this tick, N s/m (0: none)."},
    },
    ["energy_J", "damping"],
)

_XYZ = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_FRAME_TRANSFORM_SCHEMA = {
    "title": "foxglove.FrameTransform",
    "description": "A transform between two reference frames in 3D space (Foxglove's well-known schema, "
    "so its 3D panel draws the frames: base → flange, base → target).",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "description": "Timestamp of transform",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
        },
        "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
        "child_frame_id": {"type": "string", "description": "Name of the child frame"},
        "translation": {
            **_XYZ,
            "title": "foxglove.Vector3",
            "description": "Translation component of the transform, m",
        },
        "rotation": {
            "type": "object",
            "title": "foxglove.Quaternion",
            "description": "Rotation component of the transform",
            "properties": {k: {"type": "number"} for k in "xyzw"},
        },
    },
}
TF_INTERVAL_NS = 20_000_000
"""``/tf`` is written at most every 20 ms (50 Hz: what a 3D view needs, a sliver of the pose stream's cost)."""

_EVENT_SCHEMA = _schema(
    "hapticlab.Event",
    "Something a person reviewing the session should know about.",
    {
        "kind": {"type": "string", "description": "Short machine-readable tag, e.g. haptic_disabled, converged."},
        "message": {"type": "string", "description": "One human-readable line."},
        "data": {"type": "object", "description": "Optional details (SI units, frames in the names)."},
    },
    ["kind", "message"],
)

#: Fixed topics -> JSON schema. Estimator topics (``/estimator/<name>``) use :data:`ESTIMATOR_SCHEMA`.
TOPICS: dict[str, dict[str, Any]] = {
    "/sensor/wrench": _WRENCH_SCHEMA,
    "/kinematics/pose": _POSE_SCHEMA,
    "/aligned/sample": _ALIGNED_SCHEMA,
    "/haptic/command": _COMMAND_SCHEMA,
    "/haptic/state": _STATE_SCHEMA,
    "/robot/target": _TARGET_SCHEMA,
    "/haptic/passivity": _PASSIVITY_SCHEMA,
    "/tf": _FRAME_TRANSFORM_SCHEMA,
    "/events": _EVENT_SCHEMA,
}
ESTIMATOR_SCHEMA = _ESTIMATOR_SCHEMA
#: Schema title -> JSON schema, every schema a recording may contain.
SCHEMAS: dict[str, dict[str, Any]] = {s["title"]: s for s in (*TOPICS.values(), ESTIMATOR_SCHEMA)}


def schema_for_topic(topic: str) -> dict[str, Any]:
    """The JSON schema of ``topic``; ``ValueError`` naming the topic when it is not a recording topic."""
    schema = TOPICS.get(topic)
    if schema is not None:
        return schema
    if topic.startswith(ESTIMATOR_TOPIC_PREFIX):
        name = topic[len(ESTIMATOR_TOPIC_PREFIX) :]
        if _ESTIMATOR_NAME.match(name):
            return ESTIMATOR_SCHEMA
        raise ValueError(
            f"bad estimator topic {topic!r}: the name after /estimator/ must be letters, digits, '_', '.' or '-'"
        )
    raise ValueError(f"unknown recording topic {topic!r}; known topics: {', '.join(TOPICS)}, /estimator/<name>")


# --------------------------------------------------------------------------
# Block schemas (format 2): one message per block of samples on the sensor-rate topics.
# --------------------------------------------------------------------------

#: Fields of an estimator block that describe its last sample only (not arrays over the samples).
BLOCK_LAST_SAMPLE_FIELDS = ("params", "cov_diag")


def _column(item: dict[str, Any], description: str) -> dict[str, Any]:
    return {"type": "array", "items": item, "description": description + " One element per sample."}


def _block_schema(sample: dict[str, Any], what: str, last_sample: tuple[str, ...] = ()) -> dict[str, Any]:
    """The block schema of a per-sample schema: every field an array over the samples, plus ``t_ns``."""
    props: dict[str, Any] = {
        "t_ns": _column(
            {"type": "integer", "minimum": 0},
            "Time of each sample, integer ns on the session's monotonic clock (the message's log time is "
            "the last sample's).",
        )
    }
    for name, prop in sample["properties"].items():
        if name in last_sample:
            props[name] = {
                **prop,
                "description": prop["description"] + " As of the block's last sample; "
                "absent when not reported with this block.",
            }
        else:
            props[name] = _column({k: v for k, v in prop.items() if k != "description"}, prop["description"])
    return _schema(
        sample["title"] + "Block",
        f"A block of {what}, columnar: element i of every array is sample i.",
        props,
        ["t_ns", *sample["required"]],
    )


#: Topics written in blocks (format 2) -> block schema. Estimator topics use :data:`ESTIMATOR_BLOCK_SCHEMA`.
BLOCK_TOPICS: dict[str, dict[str, Any]] = {
    "/sensor/wrench": _block_schema(_WRENCH_SCHEMA, "raw force/torque sensor readings"),
    "/aligned/sample": _block_schema(_ALIGNED_SCHEMA, "wrench samples with the robot orientation at their times"),
}
ESTIMATOR_BLOCK_SCHEMA = _block_schema(
    _ESTIMATOR_SCHEMA, "one estimator's outputs (channel /estimator/<name>)", BLOCK_LAST_SAMPLE_FIELDS
)
#: Titles of the block schemas: a channel with one of these holds block messages.
BLOCK_SCHEMA_TITLES = frozenset(s["title"] for s in (*BLOCK_TOPICS.values(), ESTIMATOR_BLOCK_SCHEMA))
SCHEMAS.update({s["title"]: s for s in (*BLOCK_TOPICS.values(), ESTIMATOR_BLOCK_SCHEMA)})


def block_schema_for_topic(topic: str) -> dict[str, Any]:
    """The block schema of a sensor-rate ``topic``; ``ValueError`` for a topic that is not written in blocks."""
    schema = BLOCK_TOPICS.get(topic)
    if schema is not None:
        return schema
    if topic.startswith(ESTIMATOR_TOPIC_PREFIX):
        schema_for_topic(topic)  # the ValueError for a bad estimator name
        return ESTIMATOR_BLOCK_SCHEMA
    schema_for_topic(topic)  # the ValueError for an unknown topic
    raise ValueError(
        f"{topic} is written one message per sample, not in blocks; block topics: "
        f"{', '.join(BLOCK_TOPICS)}, /estimator/<name>"
    )
