"""The block topics as ROS 2 messages (format 3): each block topic's CDR layout and message definition.

A :class:`CdrBlock` lists a topic's per-sample fields (:class:`CdrColumn`: a
ROS 2 sequence of ``width`` values per sample) in order, and for an estimator
the report of its last sample (``params``, ``cov_diag``). Its
:attr:`~CdrBlock.definition` is the ``.msg`` text recorded as the channel's
schema (encoding ``ros2msg``, which Foxglove reads natively); :mod:`.cdr`
encodes and decodes the messages.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hapticlab.sessions.recording.schemas import BLOCK_LAST_SAMPLE_FIELDS, block_schema_for_topic

#: The 4-byte CDR encapsulation header: plain CDR, little-endian.
CDR_HEADER = b"\x00\x01\x00\x00"


@dataclass(frozen=True, slots=True)
class CdrColumn:
    """One per-sample field of a CDR block: a ROS 2 sequence of ``width`` values per sample, row-major."""

    name: str
    ros_type: str  # "int64", "float64" or "bool"
    width: int  # values per sample (3 for a 3-vector, 1 for a scalar)
    doc: str

    @property
    def dtype(self) -> np.dtype:
        return _CDR_DTYPES[self.ros_type]

    @property
    def ros_name(self) -> str:
        """The field's name in the message definition: ROS 2 field names are lower case (``force_s``)."""
        return self.name.lower()


_CDR_DTYPES = {"int64": np.dtype("<i8"), "float64": np.dtype("<f8"), "bool": np.dtype("?")}


@dataclass(frozen=True, slots=True)
class CdrBlock:
    """A block topic's CDR layout: ``columns`` in order, then (estimators) the last sample's report."""

    name: str  # the schema name, ROS 2 style (package/msg/Type)
    columns: tuple[CdrColumn, ...]
    report: bool = False  # ends in ``string params``, ``float64[] cov_diag``, ``bool has_cov_diag``
    description: str = ""
    field_names: frozenset[str] = field(init=False)  # what a block message may hold

    def __post_init__(self) -> None:
        names = [c.name for c in self.columns] + (list(BLOCK_LAST_SAMPLE_FIELDS) if self.report else [])
        object.__setattr__(self, "field_names", frozenset(names))

    @property
    def definition(self) -> str:
        """The ROS 2 message definition (``.msg`` text), the schema data."""
        lines = [
            f"# {self.description}",
            "# Columnar: every array holds its samples in order, row-major "
            "(a 3-vector is 3 values per sample). An empty array: the field was not recorded with this block.",
            "# Non-finite values (NaN, inf) are recorded as they are. Frame letters are lower case here "
            "(ROS 2 field names): force_s is hapticlab's force_S.",
        ]
        for c in self.columns:
            lines.append(f"{c.ros_type}[] {c.ros_name}  # {c.doc} ({c.name})")
        if self.report:
            lines += [
                "string params  # JSON object name -> list of floats, as of the block's last sample; "
                "empty when not reported with this block (non-finite numbers as null)",
                "float64[] cov_diag  # diagonal of the parameter covariance as of the block's last sample",
                "bool has_cov_diag  # cov_diag was reported with this block",
            ]
        return "\n".join(lines) + "\n"


def _col(name: str, ros_type: str, width: int, doc: str) -> CdrColumn:
    return CdrColumn(name, ros_type, width, doc)


_T_NS = _col(
    "t_ns",
    "int64",
    1,
    "time of each sample, ns on the session's monotonic clock (log time: the last + clock_offset_ns)",
)


_SENSOR = (
    _col("force_S", "float64", 3, "raw force in the sensor frame S, N (fx, fy, fz per sample)"),
    _col("torque_S", "float64", 3, "raw torque in S about the sensor origin, N·m (3 per sample)"),
)


_SEQ_STATUS = (
    _col("seq", "int64", 1, "sensor sequence number"),
    _col("status", "int64", 1, "sensor status bits; 0 = good, 1 = saturated, 2 = device error"),
)


#: Block topics -> CDR layout (format 3). Estimator topics use :data:`ESTIMATOR_CDR_BLOCK`.
CDR_BLOCKS: dict[str, CdrBlock] = {
    "/sensor/wrench": CdrBlock(
        "hapticlab/msg/SensorWrenchBlock",
        (_T_NS, *_SENSOR, *_SEQ_STATUS),
        description="A block of raw force/torque sensor readings (/sensor/wrench).",
    ),
    "/aligned/sample": CdrBlock(
        "hapticlab/msg/AlignedSampleBlock",
        (
            _T_NS,
            *_SENSOR,
            _col(
                "quat_BE",
                "float64",
                4,
                "orientation R_BE of E in B at the sample's time, unit quaternion w, x, y, z (4 per sample)",
            ),
            *_SEQ_STATUS,
            _col("stale", "bool", 1, "orientation held longer than one kinematics period"),
        ),
        description="A block of wrench samples with the robot orientation at their own times (/aligned/sample).",
    ),
}


ESTIMATOR_CDR_BLOCK = CdrBlock(
    "hapticlab/msg/EstimatorEstimateBlock",
    (
        _T_NS,
        _col("contact_force_S", "float64", 3, "estimated contact force in S, N (3 per sample)"),
        _col("contact_torque_S", "float64", 3, "estimated contact torque in S, N·m (3 per sample)"),
        _col("contact", "bool", 1, "the estimator judged the sample to be in contact"),
        _col("converged_force", "bool", 1, "the force stage has converged"),
        _col("converged_torque", "bool", 1, "the torque stage has converged"),
    ),
    report=True,
    description="A block of one estimator's outputs (/estimator/<name>).",
)


#: Schema name -> CDR layout, every CDR block schema a recording may contain.
CDR_BLOCK_SCHEMAS: dict[str, CdrBlock] = {b.name: b for b in (*CDR_BLOCKS.values(), ESTIMATOR_CDR_BLOCK)}


def cdr_block_for_topic(topic: str) -> CdrBlock:
    """The CDR layout of a block ``topic``; ``ValueError`` as :func:`block_schema_for_topic`."""
    block_schema_for_topic(topic)  # the ValueError for topics not written in blocks
    return CDR_BLOCKS.get(topic, ESTIMATOR_CDR_BLOCK)
