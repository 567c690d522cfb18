"""The plugin contract: the plain-object interfaces the run loop calls, and their optional capabilities.

Factories registered through the hooks return objects with these methods. The
host builds them once; in the loop it only calls methods (no hook calls).
Options come from the session's TOML table for the plugin, checked against the
factory's signature (see ``hapticlab.core.host.registry.validate_options``).

Besides the required interface, an object may have **capabilities**: the small
Protocols below. The host checks them once, when it builds the session
(``isinstance(obj, Capability)``), and keeps what it found; nothing in the
per-sample loop probes an object for an attribute. ``docs/plugins.md`` lists
every interface and capability with its exact signature (a test checks it).

Keyword arguments the host may provide to a factory that accepts them are the
session's *contexts* (``register_contexts``), e.g. ``world``: the simulated
world built from the session's ``[world]`` table.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from hapticlab.core.types import (
    AlignedSamples,
    DeviceState,
    Estimates,
    Event,
    HapticCommand,
    PoseSample,
    WrenchBlock,
    WrenchSample,
)


@runtime_checkable
class SensorSource(Protocol):
    """A six-axis force/torque sensor.

    ``rate_hz`` is the nominal sample rate. ``open(t0_ns)`` starts streaming,
    with ``t0_ns`` the session clock at start. ``read(until_ns)`` returns every
    sample not yet returned whose time is <= ``until_ns`` (a real device returns
    what has arrived), in time order. ``close()`` releases the device.
    """

    rate_hz: float

    def open(self, t0_ns: int) -> None: ...
    def read(self, until_ns: int) -> list[WrenchSample]: ...
    def close(self) -> None: ...


@runtime_checkable
class KinematicsSource(Protocol):
    """Robot forward kinematics: the orientation (and position) of E in B over time.

    Same life cycle as SensorSource; ``read`` returns PoseSample records.
    """

    rate_hz: float

    def open(self, t0_ns: int) -> None: ...
    def read(self, until_ns: int) -> list[PoseSample]: ...
    def close(self) -> None: ...


@runtime_checkable
class Estimator(Protocol):
    """Separates the contact wrench from the non-contact part, sample by sample: the contract's minimum.

    ``update_block`` consumes a block of aligned samples in time order and returns their Estimates, one row
    per sample: the contact wrench in S and, per sample, whether it is a contact and whether each stage has
    converged. That is all the host needs to record an estimator and compare it with others. What it reports
    besides (its parameters, their covariance and std, events) is optional: the capabilities below.
    """

    def update_block(self, block: AlignedSamples) -> Estimates: ...


@runtime_checkable
class HapticOutput(Protocol):
    """A haptic master device that renders force commands.

    ``rate_hz`` is the device's command rate. ``send`` renders one command
    (already clamped and rate-limited by the host). ``state`` returns the latest
    device state, or None if the device reports none.
    """

    rate_hz: float

    def open(self) -> None: ...
    def send(self, command: HapticCommand) -> None: ...
    def state(self) -> DeviceState | None: ...
    def close(self) -> None: ...


# ---------------------------------------------------------------- optional capabilities


@runtime_checkable
class ReportsParams(Protocol):
    """An estimator that reports what it has identified.

    ``params()`` maps physical names to lists of floats (SI units, the frame in the name), recorded on
    ``/estimator/<name>`` at 10 Hz and in the session summary. The paper's model names its parameters
    ``gravity_force_B``, ``bias_force_S``, ``cog_S``, ``bias_torque_S``: an estimator that reports
    ``gravity_force_B`` and ``bias_force_S`` lets the host check, while the haptics are on, that the robot's
    poses are in step with the wrench (``sessions.live.watch``); the primary estimator must, or the haptic
    force stays off ("<label> reports no weight model").
    """

    def params(self) -> dict[str, list[float]]: ...


WEIGHT_MODEL = ("gravity_force_B", "bias_force_S")
"""The parameters the host needs from the primary estimator to drive the haptics (``ReportsParams``)."""


@runtime_checkable
class ReportsCovariance(Protocol):
    """An estimator that reports its state's covariance diagonal (``cov_diag()``, recorded beside ``params``)."""

    def cov_diag(self) -> list[float]: ...


def params_of(estimator: object) -> dict[str, list[float]]:
    """An estimator's ``params()``, or {} when it reports none (offline tools, once per run)."""
    return estimator.params() if isinstance(estimator, ReportsParams) else {}


def cov_diag_of(estimator: object) -> list[float]:
    """An estimator's ``cov_diag()``, or [] when it reports none (offline tools, once per run)."""
    return estimator.cov_diag() if isinstance(estimator, ReportsCovariance) else []


@runtime_checkable
class EmitsEvents(Protocol):
    """Something a person reviewing the session should know about (any plugin kind).

    ``drain_events()`` returns the events since the last call (and forgets
    them); the loop records them on ``/events`` after every update, with the
    plugin's label in ``data["source"]``. An estimator's ``payload_change``
    holds the haptic force at zero for a while (``sessions.live.gate``).
    """

    def drain_events(self) -> list[Event]: ...


@runtime_checkable
class ReportsParameterStd(Protocol):
    """An estimator that knows how well its force-stage parameters are identified.

    ``force_parameter_std()`` is the (6,) standard deviation of
    [gravity_force_B, bias_force_S], N. The haptic force stays off until it is
    below ``[haptic] ready_force_std``, and goes off again when it grows back
    above it.
    """

    def force_parameter_std(self) -> np.ndarray: ...


@runtime_checkable
class HoldsOutOutliers(Protocol):
    """An estimator that refuses some samples from its update without judging them a contact.

    ``held_out_samples`` counts them so far: the samples of refused runs too
    short to be a contact, lone outliers of the sensor's noise whose contact
    flag stays down (``kalman``'s ``contact_after``). Benchmarks
    report them beside the contact rows, so a refusal never goes unseen.
    """

    @property
    def held_out_samples(self) -> int: ...


@runtime_checkable
class KnowsMount(Protocol):
    """An estimator that knows the sensor's mount on the flange.

    ``R_SE`` is the (3, 3) orientation of E in S (identity when S = E); the
    haptic mapping turns the contact force from S into the base through it.
    """

    R_SE: np.ndarray


@runtime_checkable
class CountsConvergence(Protocol):
    """An estimator that counts the sample each stage first converged at (None until then)."""

    first_converged_force: int | None
    first_converged_torque: int | None


@runtime_checkable
class SavesState(Protocol):
    """An estimator whose end state starts the next session (a warm start).

    ``state()`` is a JSON-serialisable dict; the session writes it beside its
    recording (``<recording>.calibration.json``) and as the metadata record
    ``hapticlab.estimator_state``. ``load_state(source)`` starts from such a
    dict or file, raising ``ValueError("warm_start: ...")`` when it cannot.
    """

    def state(self) -> dict[str, Any]: ...
    def load_state(self, source: str | Path | dict[str, Any]) -> None: ...


@runtime_checkable
class HasCalibration(Protocol):
    """A sensor that reports its calibration (counts per unit, serial number, ...).

    ``calibration`` is a dict of strings, recorded as the metadata record
    ``hapticlab.calibration``.
    """

    calibration: dict[str, str]


@runtime_checkable
class HasRange(Protocol):
    """A sensor that knows its measurement range.

    ``range_force_S`` (3,) N and ``range_torque_S`` (3,) N·m per axis: a reading
    beyond them with a good status is physically impossible (the sensor would
    saturate), so the session refuses it as implausible and zeroes the force.
    """

    range_force_S: np.ndarray
    range_torque_S: np.ndarray


@runtime_checkable
class Reidentifies(Protocol):
    """An estimator that can re-identify its sensor bias on request.

    ``reidentify_bias(reason)`` re-opens the bias (and what depends on it) as if
    it were unknown, keeping the rest; the estimator's convergence flags then
    drop until it has converged again. The session calls it when the residual keeps its direction in the
    sensor frame while the tool turns (a bias step or drift) rather than in the world (a contact).
    """

    def reidentify_bias(self, reason: str) -> None: ...


@runtime_checkable
class ReidentifiesWeight(Protocol):
    """An estimator that can re-identify the tool's weight on request.

    ``reidentify_weight(reason)`` re-opens the weight (``gravity_force_B``) and the centre of gravity as if
    unknown, keeping the bias. The session calls it when a sudden step keeps its direction in the world
    along gravity: a load hung on the tool or let go (or a tool lifted off what it started resting on).
    """

    def reidentify_weight(self, reason: str) -> None: ...


@runtime_checkable
class ReportsHealth(Protocol):
    """A device that counts what went wrong on its link (lost, duplicate, out-of-order, stalled records, ...).

    ``health_counters()`` returns the counts since ``open`` by name; the device
    records them itself as events (EmitsEvents) when they change. Not for the
    per-sample path: a call may ask the driver for a snapshot.
    """

    def health_counters(self) -> dict[str, int]: ...


@runtime_checkable
class HasLatency(Protocol):
    """A device whose newest sample is, in ordinary operation, up to ``latency_s`` older than now (s).

    A device on a network or polled by a thread delivers each sample some time
    after its stamp. The host adds this to its freshness rules, so the link's
    ordinary delay is not taken for a fault: a sensor's samples count as stale
    after 1.5 periods + one loop period + ``latency_s``; a pose may be
    extrapolated one period + ``latency_s`` past its stamp. A device without
    it is taken to deliver at once (the simulated ones).
    """

    latency_s: float


@runtime_checkable
class HasForceLimit(Protocol):
    """A haptic output that knows the largest force it may render, ``max_force`` (N).

    Read by the host at every command (it may change when the device opens and
    reports its own maximum): the governor clamps to the smaller of this and
    ``[haptic] max_force``, and zeroes the force when it is not a finite
    number > 0. The ``serial`` plugin's is its ``device_max_force`` option,
    lowered to the maximum the device reports in its handshake.
    """

    max_force: float


@runtime_checkable
class ServosCartesian(Protocol):
    """A robot that follows a Cartesian target for its flange E (CRTK ``servo_cp``): what teleoperation drives.

    ``servo_cp(t_ns, R_BE, p_BoEo_B)`` sends the target pose of E in B, ``R_BE`` (3, 3) and
    ``p_BoEo_B`` (3,) m, to be followed from session time ``t_ns`` on; the robot moves there
    under its own servo and limits, and the kinematics report where it actually is. Called
    at most once per loop tick, only while the session's ``[teleop]`` is on. Built-in: the
    ``sim`` kinematics when ``[world.motion] script = "servo"``; ``ur_rtde`` with ``follow = true``.
    """

    def servo_cp(self, t_ns: int, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> None: ...


@runtime_checkable
class MeasuresWrench(Protocol):
    """A robot that measures the wrench on its tool itself (CRTK ``measured_cf``): a second channel.

    Its poses carry ``PoseSample.wrench_B`` (a UR e-Series' ``actual_TCP_force``), and ``wrench_accuracy_N``
    is the largest error it states for the force, N per axis (0: it reports none). Coarse, but independent
    of the wrist sensor: the gate compares the primary estimator's contact force, turned into B, with it and
    holds the force at zero while they differ by more than that (``sessions.live.crosscheck``); a sudden step
    both channels show is a contact at once. Built-in: ``sim``, and ``ur_rtde`` with ``tcp_force_accuracy``.
    """

    wrench_accuracy_N: float


@runtime_checkable
class PreparesAhead(Protocol):
    """A sensor or kinematics source with work it can do before it is read (the simulated devices).

    ``prepare(until_ns)`` does now whatever ``read`` would have to do for the samples up to
    ``until_ns`` (ns, session clock) without handing any out: a paced loop calls it while it would
    otherwise sleep before its next tick (with the next tick's end as ``until_ns``), so the work
    leaves the path from a sample to its force command. What ``read`` returns must not depend on
    whether or when ``prepare`` was called.
    """

    def prepare(self, until_ns: int) -> None: ...


@runtime_checkable
class ReadsBlocks(Protocol):
    """A sensor that hands its readings over as arrays.

    ``read_block(until_ns)`` returns what ``read(until_ns)`` would, as one :class:`WrenchBlock` (empty when
    nothing is new); the loop then uses it instead of ``read``. A fast sensor's loop would otherwise build
    one record per sample and the same arrays from them again (at 7 kHz, 7 records a 1 ms tick). The
    arrays must not change once handed over. Hand writable, C-contiguous int64 and float64 arrays: the
    compiled stages downstream are built for those (a read-only or strided array would have them compile
    another version of themselves at the first tick).
    """

    def read_block(self, until_ns: int) -> WrenchBlock: ...


CAPABILITIES = (
    EmitsEvents,
    ReportsParameterStd,
    KnowsMount,
    CountsConvergence,
    SavesState,
    HasCalibration,
    HasRange,
    Reidentifies,
    ReidentifiesWeight,
    ReportsHealth,
    HasLatency,
    HasForceLimit,
    ServosCartesian,
    MeasuresWrench,
    PreparesAhead,
    ReadsBlocks,
)
"""Every optional capability the host looks for, in the order ``docs/plugins.md`` lists them."""
