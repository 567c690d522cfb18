"""The plain-object interfaces the run loop calls once plugins are built.

Factories registered through the hooks return objects with these methods. The
host builds them once; in the loop it only calls methods (no hook calls).
Options come from the session's TOML table for the plugin, checked against the
factory's signature (see ``hapticlab.core.plugins.validate_options``).
Keyword arguments the host may provide when the factory accepts them:
``world`` (the session's shared simulated world, for simulated devices).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from .types import AlignedSamples, DeviceState, Estimates, HapticCommand, PoseSample, WrenchSample


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
    """Separates the contact wrench from the non-contact part, sample by sample.

    ``update_block`` consumes a block of aligned samples in time order and
    returns their Estimates (one row per sample). ``params()`` reports the identified parameters with
    physical names (``gravity_force_B``, ``bias_force_S``, ``cog_S``,
    ``bias_torque_S``, ...) as lists of floats; ``cov_diag()`` the covariance
    diagonal of the estimator's state.
    """

    def update_block(self, block: AlignedSamples) -> Estimates: ...
    def params(self) -> dict[str, list[float]]: ...
    def cov_diag(self) -> list[float]: ...


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
