"""Injected faults: what a real sensor or robot does wrong, rehearsed in the simulated world.

``[[world.faults]]`` tables (``kind``, ``start`` s, ``duration`` s, and per kind
``force`` N / ``torque`` N·m / ``delay`` s and ``ramp`` s). The ``sim`` sensor and ``sim``
kinematics apply them to what they deliver (the world's physics is
untouched), so a lab can rehearse failures and an instructor can show them,
and the device emulators fed by the world inherit them.

Sensor faults:

* ``sensor_spike``: ``force``/``torque`` added to the readings while active,
  status still OK (an electrical glitch; default duration 20 ms);
* ``sensor_nan``: the readings are NaN, status OK (a broken conversion);
* ``sensor_saturated``: the saturation status bit is set;
* ``sensor_dropout``: no samples at all (a pulled cable, a lost UDP stream);
* ``sensor_bias_step``: ``force``/``torque`` added from ``start`` on (a knock,
  a temperature jump of the gauges; default duration: for good); with ``ramp``
  it grows from 0 over ``ramp`` s, then holds (the gauges drifting as they warm);
* ``sensor_stuck``: every reading repeats the first one of the fault, status OK,
  stamps fresh (a stuck converter or a frozen firmware buffer).

Kinematics faults:

* ``kinematics_freeze``: poses keep coming with fresh timestamps but hold the
  pose of the fault's start (a stuck controller thread);
* ``kinematics_delay``: each pose is the one from ``delay`` s earlier, stamped
  as current (a queue in the robot's network stack); with ``ramp`` the delay
  grows from 0 to ``delay`` over ``ramp`` s (a queue filling: no jump in the
  poses to give it away), then the queue empties at once at the end;
* ``kinematics_dropout``: no poses at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hapticlab.core.host.options import OptionError, choice, number
from hapticlab.core.types import STATUS_SATURATED

SENSOR_KINDS = ("sensor_spike", "sensor_nan", "sensor_saturated", "sensor_dropout", "sensor_bias_step", "sensor_stuck")
KINEMATICS_KINDS = ("kinematics_freeze", "kinematics_delay", "kinematics_dropout")
KINDS = SENSOR_KINDS + KINEMATICS_KINDS
DEFAULT_DURATION_S = {"sensor_spike": 0.02, "sensor_bias_step": math.inf}
"""Duration of a fault that gives none, s (the others: 1 s)."""


@dataclass(frozen=True, slots=True)
class Fault:
    """One injected fault.

    Attributes:
        kind: what goes wrong: a sensor fault or a kinematics fault, as listed above.
        start: when it starts, s of world time.
        duration: how long it lasts, s (``inf``: for good).
        force: (3,) force added by a spike or a bias step, N (in S).
        torque: (3,) torque added by a spike or a bias step, N·m (in S).
        delay: how late a delayed pose is, s.
        ramp: how long a delay or a bias step takes to build up from 0, s (0: at once).
    """

    kind: str
    start: float
    duration: float = 1.0
    force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque: tuple[float, float, float] = (0.0, 0.0, 0.0)
    delay: float = 0.0
    ramp: float = 0.0

    def __post_init__(self) -> None:
        choice("kind", self.kind, KINDS)
        number("start", self.start, hint=" (s)")
        number("duration", self.duration, above=0, finite=False, hint=" (s)")
        number("delay", self.delay, minimum=0, hint=" (s)")
        number("ramp", self.ramp, minimum=0, hint=" (s)")
        if self.kind == "kinematics_delay" and not self.delay > 0:
            raise OptionError("delay", f"must be a finite number > 0 for a kinematics_delay (s), got {self.delay!r}")

    def active(self, t: np.ndarray) -> np.ndarray:
        """(N,) bool: the fault acts at world times ``t`` (s)."""
        return (t >= self.start) & (t < self.start + self.duration)


_WINDOWS: dict[int, tuple[tuple[Fault, ...], np.ndarray, np.ndarray]] = {}
_STUCK: dict[int, tuple[Fault, np.ndarray, np.ndarray]] = {}
"""A ``sensor_stuck`` fault's reading (force, torque), from the first sample it acted on."""


def _acting(faults: tuple[Fault, ...], t: np.ndarray) -> list[Fault]:
    """The faults whose window meets [min t, max t]: one vectorised test over the whole list (the
    list's start and end times are kept per list, so a hundred faults cost microseconds per read)."""
    cached = _WINDOWS.get(id(faults))
    if cached is None or cached[0] is not faults:
        starts = np.array([f.start for f in faults], dtype=float)
        cached = _WINDOWS[id(faults)] = (faults, starts, starts + np.array([f.duration for f in faults]))
    _, starts, ends = cached
    hit = (starts <= t.max()) & (ends > t.min())
    return [faults[i] for i in np.flatnonzero(hit)]


def apply_sensor_faults(faults: tuple[Fault, ...], t: np.ndarray, reading: dict[str, np.ndarray]) -> np.ndarray:
    """Apply the sensor faults to a reading at world times ``t`` in place; the (N,) mask of samples delivered."""
    keep = np.ones(len(t), dtype=bool)
    if not len(t):
        return keep
    for fault in _acting(faults, t):
        if fault.kind not in SENSOR_KINDS:
            continue
        on = fault.active(t)
        if not on.any():
            continue
        if fault.kind in ("sensor_spike", "sensor_bias_step"):
            grown = np.clip((t[on] - fault.start) / fault.ramp, 0.0, 1.0)[:, None] if fault.ramp > 0 else 1.0
            reading["force_S"][on] += grown * np.asarray(fault.force)
            reading["torque_S"][on] += grown * np.asarray(fault.torque)
        elif fault.kind == "sensor_stuck":
            first = int(np.argmax(on))  # the fault's first sample here; the first of all, kept across reads
            if id(fault) not in _STUCK or _STUCK[id(fault)][0] is not fault:
                _STUCK[id(fault)] = (fault, reading["force_S"][first].copy(), reading["torque_S"][first].copy())
            _, reading["force_S"][on], reading["torque_S"][on] = _STUCK[id(fault)]
        elif fault.kind == "sensor_nan":
            reading["force_S"][on] = np.nan
            reading["torque_S"][on] = np.nan
        elif fault.kind == "sensor_saturated":
            reading["status"][on] |= STATUS_SATURATED
        else:  # sensor_dropout
            keep &= ~on
    return keep


def kinematics_faults_act(faults: tuple[Fault, ...], t: np.ndarray) -> bool:
    """A kinematics fault acts at some of the world times ``t`` (s) (else the poses are the world's own)."""
    return bool(faults) and len(t) > 0 and any(f.kind in KINEMATICS_KINDS for f in _acting(faults, t))


def kinematics_times(faults: tuple[Fault, ...], t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For poses stamped ``t`` (s): the world times whose pose the robot reports, the times whose encoder
    reading it reports (a frozen controller repeats one message, jitter and all), and the mask delivered."""
    t_pose = np.array(t, dtype=float)
    t_reading = np.array(t, dtype=float)
    keep = np.ones(len(t), dtype=bool)
    if not len(t):
        return t_pose, t_reading, keep
    for fault in _acting(faults, t):
        if fault.kind not in KINEMATICS_KINDS:
            continue
        on = fault.active(t)
        if fault.kind == "kinematics_freeze":
            t_pose[on] = t_reading[on] = fault.start
        elif fault.kind == "kinematics_delay":
            built = np.clip((t[on] - fault.start) / fault.ramp, 0.0, 1.0) if fault.ramp > 0 else 1.0
            t_pose[on] = t_pose[on] - fault.delay * built
        else:  # kinematics_dropout
            keep &= ~on
    return t_pose, t_reading, keep
