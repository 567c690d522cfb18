"""The ``netft`` sensor's two receivers behind one small interface (``open``, ``poll``, ``counters``, ...).

* :class:`HapticlabLink` (``receiver = "hapticlab"``): hapticlab's own
  :class:`~hapticlab.plugins.sensors.rdt.RdtReceiver`, the calibration read from
  ``netftapi2.xml``; it hands over counts.
* :class:`PynetftLink` (``receiver = "pynetft"``): the community client on its
  own thread, its bounded queue drained at each poll; it hands over values in
  the sensor's units, and restarts its stream after any record whose status
  word reports an error.

Both give an :class:`~hapticlab.plugins.sensors.rdt.RdtBatch` per poll, so the
sensor (``netft.py``) converts, stamps and watches one shape of data.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from hapticlab.plugins.sensors.netft_protocol import Calibration, fetch_configuration
from hapticlab.plugins.sensors.rdt import RdtBatch, RdtReceiver

if TYPE_CHECKING:
    import pynetft


class LinkSettings(Protocol):
    """What a receiver reads of the sensor's options (:class:`~hapticlab.plugins.sensors.netft.NetFTSensor`)."""

    address: str
    rdt_port: int
    http_port: int
    receive_timeout: float
    connect_timeout: float
    reconnect_delay: float
    recovery: str
    queue_size: int
    override: Calibration | None


class HapticlabLink:
    """The ``hapticlab`` receiver (:class:`.rdt.RdtReceiver`) with the calibration from ``netftapi2.xml``."""

    scaled = False  # hands over counts

    def __init__(self, sensor: LinkSettings):
        self.sensor = sensor
        self.rdt = RdtReceiver(sensor.address, sensor.rdt_port)

    def open(self) -> tuple[str, Calibration]:
        s = self.sensor
        where = f"no Net F/T record from {s.address}:{s.rdt_port} within {s.connect_timeout:g} s"
        try:
            product, calibration = fetch_configuration(s.address, s.http_port, s.connect_timeout)
        except (OSError, ValueError) as exc:
            if s.override is None:
                raise ConnectionError(f"{where} (netftapi2.xml from port {s.http_port}: {exc})") from None
            product, calibration = "ATI Net F/T (netftapi2.xml unread)", s.override
        calibration = s.override or calibration
        self.rdt.open()
        if not self.rdt.wait(s.connect_timeout):
            self.rdt.close()
            raise ConnectionError(f"{where} (start request sent, nothing came back)")
        return product, calibration

    def poll(self) -> RdtBatch | None:
        return self.rdt.poll()

    def counters(self) -> dict[str, int]:
        return self.rdt.counters

    def on_timeout(self) -> None:
        self.rdt.counters["timeout"] += 1

    def restart(self) -> None:
        self.rdt.restart()

    def close(self) -> None:
        self.rdt.close()


class PynetftLink:
    """The ``pynetft`` receiver: pynetft's Client on its own thread, its queue drained at each read."""

    scaled = True  # hands over values in the sensor's units

    def __init__(self, sensor: LinkSettings):
        import pynetft

        self.pynetft, self.sensor = pynetft, sensor
        self.client: pynetft.Client | None = None
        self._ft: int | None = None  # the last ft_sequence as sent
        self._k = 0  # ... unwrapped

    def open(self) -> tuple[str, Calibration]:
        pynetft, s = self.pynetft, self.sensor
        override = (
            None
            if s.override is None
            else pynetft.Calibration(
                s.override.counts_per_force,
                s.override.counts_per_torque,
                pynetft.ForceUnit(s.override.force_unit),
                pynetft.TorqueUnit(s.override.torque_unit),
            )
        )
        config = pynetft.Config(
            sensor_host=s.address,
            rdt_port=s.rdt_port,
            http_port=s.http_port,
            receive_timeout=s.receive_timeout,
            configuration_timeout=s.connect_timeout,
            configuration_connect_timeout=min(0.5, s.connect_timeout),
            reconnect_initial_delay=s.reconnect_delay,
            reconnect_max_delay=max(5.0, s.reconnect_delay),
            deliver_samples_with_error_status=True,  # saturation must reach the stream, not vanish
            recovery_policy=pynetft.RecoveryPolicy.RECONNECT
            if s.recovery == "reconnect"
            else pynetft.RecoveryPolicy.FAIL_STOP,
            calibration_override=override,
        )
        self.client = pynetft.Client(config, queue_size=s.queue_size)
        self.client.start()
        if not self.client.wait_for_first_sample(s.connect_timeout):
            health = self.client.health()
            self.client.stop()
            raise ConnectionError(
                f"no Net F/T record from {s.address}:{s.rdt_port} within "
                f"{s.connect_timeout:g} s ({health.last_error or health.state.value})"
            )
        configuration = self.client.health().sensor_configuration
        c = configuration.calibration  # type: ignore[union-attr]  # known once a first sample came
        return configuration.product_name, Calibration(  # type: ignore[union-attr]  # known once a first sample came
            c.counts_per_force_unit, c.counts_per_torque_unit, c.force_unit.value, c.torque_unit.value
        )

    def poll(self) -> RdtBatch | None:
        batch = []
        try:
            for sample in self.client.samples(timeout=0.0):  # type: ignore[union-attr]  # open() made it
                batch.append(sample)
        except TimeoutError:  # nothing more queued
            pass
        except self.pynetft.SensorFaultError as exc:  # fail_stop: the stream is over
            raise ConnectionError(
                f"Net F/T {self.sensor.address} stopped: {exc.fault_code.value} ({exc.health.last_error})"
            ) from None
        if not batch:
            return None
        ft = np.array([sample.ft_sequence for sample in batch], dtype=np.int64)
        if self._ft is None:
            self._ft = self._k = int(ft[0])
        step = np.diff(ft, prepend=self._ft) & 0xFFFF_FFFF
        backward = np.flatnonzero(step >= 2**31)  # pynetft delivers a backward ft_sequence only as a restart
        restarts = [(int(i), int(ft[i - 1]) if i else self._ft, int(ft[i])) for i in backward]
        step[backward] = 1
        k = self._k + np.cumsum(step)
        self._ft, self._k = int(ft[-1]), int(k[-1])
        return RdtBatch(
            k,
            np.array([sample.status for sample in batch], dtype=np.int64),
            np.array([sample.wrench for sample in batch]),
            np.array([sample.received_at_ns for sample in batch], dtype=np.int64),
            restarts,
        )

    def counters(self) -> dict[str, int]:
        h = self.client.health()  # type: ignore[union-attr]  # open() made it
        return {
            "received": h.received_count,
            "lost": h.lost_count,
            "duplicate": h.duplicate_count,
            "out_of_order": h.out_of_order_count,
            "stall": h.ft_stall_count,
            "ft_backward": h.ft_backward_count,
            "ft_restart": h.ft_restart_count,
            "malformed": h.malformed_count,
            "timeout": h.timeout_count,
            "reconnect": h.reconnect_count,
            "device_error": h.device_error_count,
            "warning": h.warning_count,
            "queue_dropped": h.python_queue_dropped_count,
            "calibration_change": h.calibration_change_count,
        }

    def on_timeout(self) -> None:
        pass  # pynetft counts its own timeouts

    def restart(self) -> None:
        pass  # pynetft reconnects by itself

    def close(self) -> None:
        self.client.stop()  # type: ignore[union-attr]  # open() made it
