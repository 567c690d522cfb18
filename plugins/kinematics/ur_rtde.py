"""The ``ur_rtde`` kinematics: a Universal Robots arm's flange pose over RTDE, through ur-rtde.

The wire is ur-rtde's ``RTDEReceiveInterface`` (SDU Robotics' client: it
negotiates RTDE protocol 2 on the controller's port 30004, sets up one output
recipe and receives its data packages on its own thread). It asks for four
outputs (five with ``actual_TCP_force``, the arm's own wrench, before the
timestamp), in this order: ``actual_TCP_pose`` (position, m, and rotation vector,
rad, of the TCP in the Base frame: with the TCP offset zero in the robot's
installation it is the flange, E), ``actual_q`` and ``actual_qd`` (the joints,
rad and rad/s: ``PoseSample.joints``/``joint_velocities``, CRTK
``measured_js``) and ``timestamp`` (s since the controller started, in steps of
its 2 ms (e-Series, 500 Hz) or 8 ms (CB3, 125 Hz) cycle).

ur-rtde keeps only the latest package and its getters read one field each, so
a thread here polls the timestamp a few times per period, and on a new one
reads the pose, the joints and the timestamp again; the sample is kept only
when both timestamps agree (a package that arrived in between is read on the
next turn). A step of the controller's timestamp larger than one period counts
the packages missed (``packages_missed``; an event at most once a second).

**Clock**: a pose's time is its controller timestamp mapped onto the session's
monotonic clock by the lower envelope of (receipt time − controller time)
(``DeviceClock``, as for the Net F/T): spaced by the controller's own clock,
never later than its receipt, following the controller's crystal within
200 ppm. A timestamp that goes backwards (the controller restarted) re-anchors it.

**Fail-safe**: when packages stop (the controller or the network gone) no new
pose is returned, so the session's aligner marks the wrench samples' orientation
stale after one kinematics period and the haptic force goes to zero; a
``kinematics_timeout`` event says so after ``receive_timeout`` (and
``kinematics_resumed`` if the packages come back on the same connection). A
lost connection is not re-opened within the session: ur-rtde 1.6.5's
``reconnect()`` after a failed attempt can leave the interface "connected" to
a dead socket, and disconnecting or destroying it then aborts the process
(``std::terminate`` on "write: Broken pipe"), which would lose the
recording's end. Start a new session once the controller is back.

Options (``[kinematics]``): :class:`URRTDEKinematics`'s, and ``follow`` (the arm also follows
teleoperation's targets: :class:`FollowingURRTDEKinematics`, ``ur_follow.py``).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.frames import matrix_from_quat_wxyz, quat_from_rotvec
from hapticlab.core.host.options import OptionError, choice, host_address, number
from hapticlab.core.types import Event, PoseSample
from hapticlab.plugins.device_clock import DeviceClock
from hapticlab.plugins.kinematics.ur_arm import UR5E_FORCE_ACCURACY_N, UR_DH, URArm
from hapticlab.plugins.kinematics.ur_follow import TargetWriter

VARIABLES = ["actual_TCP_pose", "actual_q", "actual_qd", "timestamp"]
"""The outputs asked for; ``timestamp`` last, so a package's timestamp changes after its other fields."""
WITH_FORCE = ["actual_TCP_pose", "actual_q", "actual_qd", "actual_TCP_force", "timestamp"]
"""The outputs asked for with ``tcp_force_accuracy`` > 0: the arm's own wrench too (``PoseSample.wrench_B``)."""
MAX_RATE_HZ = 500.0
"""The fastest RTDE output (e-Series); a CB3 controller streams at most 125 Hz."""
CLOCK_TICKS_HZ = 1e6
"""Controller timestamps are mapped to µs ticks for the clock mapping (every UR cycle is a whole number of them)."""
TCP_CHECK_M = 0.005
TCP_CHECK_RAD = 0.01
"""With ``model`` set, a first pose further than this from the flange's nominal FK (m, rad) is an event;
a controller's calibrated kinematics differ from the nominal DH by about a millimetre."""
FIRST_PACKAGE_TIMEOUT_S = 1.0
"""``open`` waits this long for the first data package, s."""
MAX_TIMESTAMP_S = 1e9
"""A controller timestamp (s since it started) past this (32 years) is a damaged package's, not a clock's."""
MISSED_EVENT_INTERVAL_NS = 1_000_000_000
"""Missed packages are reported at most this often, ns."""
FOLLOW_RATE_HZ = 125.0
"""Teleoperation targets written a second by default (``follow_rate_hz``): a CB3's cycle, a quarter of an e-Series'."""
POLL_LATENCY_S = 0.002
"""The polling thread's share of a pose's age at the loop, s (it polls 4× a period, but waits for the
interpreter's lock while the loop runs a tick)."""


class URRTDEKinematics:
    """A UR arm's flange pose and joints over RTDE (KinematicsSource, EmitsEvents), and its own wrench
    (MeasuresWrench).

    Parameters
    ----------
    address : the controller's IP address or host name (RTDE port 30004).
    rate_hz : RTDE output frequency, Hz, within (0, 500]; a CB3 controller refuses more than 125.
    receive_timeout : no package for this long is a ``kinematics_timeout`` event, s.
    model : the arm's model (a key of ``ur_arm.UR_DH``, e.g. "ur5e"), or "" to skip the check: the first
        package's ``actual_TCP_pose`` is compared with the forward kinematics of its ``actual_q``; more
        than ``TCP_CHECK_M`` or ``TCP_CHECK_RAD`` apart is a ``kinematics_tcp_offset`` event (the
        installation's TCP is not the flange, so the poses are not E's).
    tcp_force_accuracy : the force accuracy of the arm's own ``actual_TCP_force`` (the payload set in its
        installation taken out), N per axis, which the session checks the wrist sensor against (default the
        UR5e's 4.0 N; a CB3's, from its joint currents, is far coarser). 0: not read. docs/devices.md.
    """

    def __init__(
        self,
        address: str = "",
        rate_hz: float = 500.0,
        receive_timeout: float = 0.1,
        model: str = "",
        tcp_force_accuracy: float = UR5E_FORCE_ACCURACY_N,
    ):
        if not address:
            raise OptionError(
                "address",
                'must be the UR controller\'s IP address or host name (e.g. address = "192.168.1.10"), got none',
            )
        host_address("address", address)
        self.rate_hz = number("rate_hz", rate_hz, above=0, maximum=MAX_RATE_HZ, hint=" Hz (e-Series 500, CB3 125)")
        receive_timeout = number("receive_timeout", receive_timeout, above=0, maximum=1.0, hint=" s")
        if model:
            choice("model", model, list(UR_DH), hint=' (or "" for no check)')
        self.arm = URArm(model) if model else None
        self.address = address
        self.wrench_accuracy_N = number("tcp_force_accuracy", tcp_force_accuracy, minimum=0, maximum=1e3, hint=" N")
        """The stated accuracy of the poses' ``wrench_B``, N per axis (MeasuresWrench; 0: not read)."""
        self.variables = WITH_FORCE if self.wrench_accuracy_N > 0 else VARIABLES
        self.latency_s = 1.0 / self.rate_hz + POLL_LATENCY_S
        """How much older than now the newest pose can be in ordinary operation (HasLatency), s: the
        controller's package pipeline (one period) and the polling thread's wait for the GIL."""
        self.receive_timeout_ns = int(receive_timeout * 1e9)
        self.clock = DeviceClock(CLOCK_TICKS_HZ)
        self.packages = 0
        """Packages received (each one pose)."""
        self.packages_missed = 0
        self.packages_bad, self._next_bad_event_ns, self._last_bad = 0, 0, ""  # skipped: impossible timestamps
        """Packages the controller sent that were never read (gaps in its timestamps)."""
        self._rtde: Any = None  # an rtde_receive.RTDEReceiveInterface while open (ur-rtde ships no types)
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._lock = threading.Lock()
        self._pending: deque[PoseSample] = deque()
        self._events: list[Event] = []
        self._last_ticks: int | None = None
        self._last_received_ns = 0
        self._timed_out = False
        self._missed_reported = 0
        self._next_missed_event_ns = 0

    # ------------------------------------------------------------------ KinematicsSource

    def open(self, t0_ns: int) -> None:
        """Connect (RTDE protocol 2, one output recipe at ``rate_hz``), start receiving, wait for the first package.

        ur-rtde does not report a refused output recipe (a CB3 asked for more than
        125 Hz answers recipe id 0 and sends nothing): no package within
        ``FIRST_PACKAGE_TIMEOUT_S`` is a ConnectionError saying so.
        """
        self._rtde = self._connect()
        self._last_received_ns = time.monotonic_ns()
        self._closing.clear()
        self._thread = threading.Thread(target=self._receive, name=f"ur_rtde {self.address}", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + FIRST_PACKAGE_TIMEOUT_S
        while self.packages == 0 and time.monotonic() < deadline:
            time.sleep(0.005)
        if self.packages == 0:
            self.close()
            raise ConnectionError(
                f"UR controller {self.address}:30004 (RTDE at {self.rate_hz:g} Hz): connected, but no "
                f"data package within {FIRST_PACKAGE_TIMEOUT_S:g} s; the controller refused the "
                f"output recipe (a CB3 streams at most 125 Hz: set kinematics.rate_hz = 125) "
                f"or is not running"
            )

    def read(self, until_ns: int) -> list[PoseSample]:
        """Every pose received and not yet returned with time <= ``until_ns``, in time order."""
        out: list[PoseSample] = []
        with self._lock:
            while self._pending and self._pending[0].t_ns <= until_ns:
                out.append(self._pending.popleft())
        return out

    def close(self) -> None:
        """Stop receiving and disconnect; the missed packages not yet reported (the events are at most one a
        second) are reported now, so the recording holds every one."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._report_missed(time.monotonic_ns())
        if self._rtde is not None:
            with contextlib.suppress(RuntimeError):  # the controller has gone: nothing left to close
                self._rtde.disconnect()
            self._rtde = None

    def drain_events(self) -> list[Event]:
        """The events since the last call: timeouts, returns, missed packages, controller restarts."""
        with self._lock:
            events, self._events = self._events, []
        return events

    # ------------------------------------------------------------------ the receive thread

    def _connect(self):
        import rtde_receive  # ur-rtde; imported here so listing the plugins does not load it

        try:
            return rtde_receive.RTDEReceiveInterface(self.address, self.rate_hz, self.variables)
        except RuntimeError as exc:
            raise ConnectionError(f"UR controller {self.address}:30004 (RTDE at {self.rate_hz:g} Hz): {exc}") from None

    def _receive(self) -> None:
        """Poll ur-rtde's latest package a few times per period; keep each new one once."""
        poll_s = 0.25 / self.rate_hz
        rtde = self._rtde
        while not self._closing.is_set():
            if not rtde.isConnected():  # the controller closed the connection: nothing more will come
                self._watch()
                self._closing.wait(0.01)
                continue
            try:
                ticks = _ticks(timestamp := rtde.getTimestamp())
                if ticks is None:  # a damaged package (a truncated one parsed as garbage): counted, skipped
                    self._bad_package(timestamp)
                    time.sleep(poll_s)
                    continue
                if ticks == self._last_ticks:
                    self._watch()
                    time.sleep(poll_s)
                    continue
                pose = rtde.getActualTCPPose()
                q = rtde.getActualQ()
                qd = rtde.getActualQd()
                wrench = rtde.getActualTCPForce() if self.wrench_accuracy_N > 0 else None
                if _ticks(rtde.getTimestamp()) != ticks:  # a newer package came in while reading: read that one
                    continue
            except RuntimeError:  # ur-rtde lost the connection under a getter
                self._watch()
                self._closing.wait(0.01)
                continue
            self._keep(ticks, time.monotonic_ns(), pose, q, qd, wrench)

    def _keep(
        self, ticks: int, received_ns: int, pose: list[float], q: list[float], qd: list[float], wrench=None
    ) -> None:
        events = []
        if self._last_ticks is not None:
            step = ticks - self._last_ticks
            if step < 0:
                self.clock.reset()
                message = (
                    f"UR controller {self.address} timestamp went back ({self._last_ticks / CLOCK_TICKS_HZ:.3f} -> "
                    f"{ticks / CLOCK_TICKS_HZ:.3f} s): controller restarted, time re-anchored"
                )
                events.append(Event(received_ns, "kinematics_restart", message))
            else:
                self.packages_missed += max(0, round(step * self.rate_hz / CLOCK_TICKS_HZ) - 1)
        self._last_ticks, self._last_bad = ticks, ""
        pose_arr = np.asarray(pose, dtype=float)
        sample = PoseSample(
            t_ns=self.clock.stamp(ticks, received_ns),
            quat_BE=quat_from_rotvec(pose_arr[3:]),
            p_BoEo_B=pose_arr[:3],
            joints=np.asarray(q, dtype=float),
            joint_velocities=np.asarray(qd, dtype=float),
            wrench_B=None if wrench is None else np.asarray(wrench, dtype=float),
        )
        if self.packages == 0 and self.arm is not None:
            events.extend(self._check_tcp(received_ns, sample))
        if self._timed_out:
            self._timed_out = False
            events.append(Event(received_ns, "kinematics_resumed", f"UR controller {self.address} streams again"))
        self._last_received_ns = received_ns
        with self._lock:
            self._pending.append(sample)
            self._events.extend(events)
            self.packages += 1  # (after the package's events: ``open`` returns on the first, and they are there)
        if received_ns >= self._next_missed_event_ns:
            self._report_missed(received_ns)

    def _bad_package(self, timestamp: float) -> None:
        """Count a package with an impossible timestamp once (ur-rtde keeps it); an event a second at most."""
        if repr(timestamp) == self._last_bad:
            return
        self.packages_bad, self._last_bad, now_ns = self.packages_bad + 1, repr(timestamp), time.monotonic_ns()
        if now_ns >= self._next_bad_event_ns:
            self._next_bad_event_ns = now_ns + MISSED_EVENT_INTERVAL_NS
            message = f"RTDE package from {self.address} skipped: timestamp {timestamp!r} s is no controller's clock"
            with self._lock:
                self._events.append(Event(now_ns, "kinematics_bad_package", message, {"bad": self.packages_bad}))

    def _report_missed(self, t_ns: int) -> None:
        """A ``kinematics_missed`` event for the packages missed since the last one (none if none were)."""
        if self.packages_missed <= self._missed_reported:
            return
        new = self.packages_missed - self._missed_reported
        self._missed_reported = self.packages_missed
        self._next_missed_event_ns = t_ns + MISSED_EVENT_INTERVAL_NS
        event = Event(
            t_ns,
            "kinematics_missed",
            f"{new} RTDE package(s) from {self.address} missed "
            f"({self.packages_missed} of {self.packages + self.packages_missed} so far)",
            {"missed": new, "missed_total": self.packages_missed, "received": self.packages},
        )
        with self._lock:
            self._events.append(event)

    def _check_tcp(self, received_ns: int, sample: PoseSample) -> list[Event]:
        """A ``kinematics_tcp_offset`` event when the reported pose is not the flange's (FK of the joints)."""
        arm: URArm = self.arm  # type: ignore[assignment]  # asked only with a model (the caller checks)
        R_reported = matrix_from_quat_wxyz(sample.quat_BE[None])[0]
        distance, angle = arm.flange_error(sample.joints, R_reported, sample.p_BoEo_B)  # type: ignore[arg-type]
        if distance <= TCP_CHECK_M and angle <= TCP_CHECK_RAD:
            return []
        return [
            Event(
                received_ns,
                "kinematics_tcp_offset",
                f"UR controller {self.address}: actual_TCP_pose is {distance * 1e3:.1f} mm and {angle:.3f} rad "
                f"from the {arm.model} flange (forward kinematics of actual_q): the installation's TCP "
                f"is not the flange; set it to zero, hapticlab needs the flange pose",
                {"distance_m": distance, "angle_rad": angle},
            )
        ]

    def _watch(self) -> None:
        """A ``kinematics_timeout`` event once the packages have stopped for ``receive_timeout``."""
        now_ns = time.monotonic_ns()
        silent_ns = now_ns - self._last_received_ns
        if not self._timed_out and silent_ns > self.receive_timeout_ns:
            self._timed_out = True
            connected = self._rtde.isConnected()
            with self._lock:
                self._events.append(
                    Event(
                        now_ns,
                        "kinematics_timeout",
                        f"no RTDE package from UR controller {self.address} for "
                        f"{silent_ns * 1e-6:.0f} ms ({'connected' if connected else 'connection lost'}): "
                        f"no fresh poses, haptic force held at zero",
                        {"silent_s": silent_ns * 1e-9, "connected": connected},
                    )
                )


def _ticks(timestamp: float) -> int | None:
    """A controller timestamp (s) as whole µs ticks; None if not finite, negative or past ``MAX_TIMESTAMP_S``."""
    if not 0.0 <= timestamp <= MAX_TIMESTAMP_S:  # NaN too
        return None
    return round(timestamp * CLOCK_TICKS_HZ)


class FollowingURRTDEKinematics(URRTDEKinematics):
    """A UR arm that also follows flange targets (ServosCartesian): ``ur_rtde`` with ``follow = true``.

    Targets go to the input registers ``hapticlab_follow.script`` reads (``ur_follow``), at most
    ``follow_rate_hz`` a second: a target within that period of the last one written waits for the
    next. Each target is seven RTDE packages (one per register, written from a process of its own:
    ``ur_target_writer.py``), and the script's ``servoj`` lookahead smooths between targets.
    """

    def __init__(self, follow_rate_hz: float = FOLLOW_RATE_HZ, **options: Any):
        super().__init__(**options)
        follow_rate_hz = number("follow_rate_hz", follow_rate_hz, above=0, maximum=self.rate_hz, hint=" Hz (rate_hz)")
        self.period_ns = round(1e9 / follow_rate_hz)
        self._writer: TargetWriter | None = None
        self._last_sent_ns: int | None = None

    def open(self, t0_ns: int) -> None:
        super().open(t0_ns)
        try:
            self._writer = TargetWriter(self.address)
        except ConnectionError:
            self.close()
            raise

    def servo_cp(self, t_ns: int, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> None:
        """Write the flange target for the controller's script (one per controller period)."""
        if self._last_sent_ns is not None and t_ns - self._last_sent_ns < self.period_ns:
            return
        self._writer.send(R_BE, p_BoEo_B)  # type: ignore[union-attr]  # open() made it
        self._last_sent_ns = t_ns

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        super().close()


def ur_rtde_kinematics(
    address: str = "",
    rate_hz: float = 500.0,
    receive_timeout: float = 0.1,
    model: str = "",
    follow: bool = False,
    follow_rate_hz: float = FOLLOW_RATE_HZ,
    tcp_force_accuracy: float = UR5E_FORCE_ACCURACY_N,
) -> URRTDEKinematics:
    """The ``ur_rtde`` kinematics (options as :class:`URRTDEKinematics`); with ``follow`` the arm also follows
    teleoperation's targets, ``follow_rate_hz`` a second (:class:`FollowingURRTDEKinematics`; run
    ``hapticlab_follow.script`` on the arm)."""
    if follow:
        return FollowingURRTDEKinematics(
            follow_rate_hz,
            address=address,
            rate_hz=rate_hz,
            receive_timeout=receive_timeout,
            model=model,
            tcp_force_accuracy=tcp_force_accuracy,
        )
    if follow_rate_hz != FOLLOW_RATE_HZ:
        raise OptionError("follow_rate_hz", f"must be left out unless follow = true, got {follow_rate_hz!r}")
    return URRTDEKinematics(address, rate_hz, receive_timeout, model, tcp_force_accuracy)


@hookimpl
def register_kinematics(register):
    """Register the Universal Robots RTDE kinematics as ``ur_rtde``."""
    register("ur_rtde", ur_rtde_kinematics)
