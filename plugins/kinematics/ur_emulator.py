"""A protocol-faithful Universal Robots controller's RTDE interface, driven by the simulated world.

It serves the RTDE wire (``rtde_protocol.py``) on port 30004 through
:class:`~hapticlab.plugins.kinematics.rtde_server.RTDEServer`: protocol 2 only,
controller version 5.x for the e-Series models and 3.x for CB3, output
frequencies within (0, 500] Hz on an e-Series, (0, 125] on a CB3. ur-rtde 1.6's
``RTDEReceiveInterface`` needs exactly this and no other port (the dashboard server on 29999 and
the URScript ports 30001–30003 are only for ``RTDEControlInterface``): ``V``, ``v``, ``O``, ``S``,
then ``U`` packages, and ``P`` when it disconnects; ``RTDEIOInterface`` adds ``I`` recipes and
``U`` packages towards the controller.

The robot: the controller's cycle is 2 ms (e-Series, 500 Hz) or 8 ms (CB3,
125 Hz) and ``timestamp`` counts cycles in seconds since the emulator started.
At a cycle where a package is due, the world's flange pose at that time gives
the joints by inverse kinematics on the continuous branch (the solution
nearest the previous q, ``ur_arm.inverse_nearest``); ``actual_q`` is that
plus the encoders' jitter (``encoder_noise``, a function of the world's seed
and the time), ``actual_TCP_pose`` (position and rotation vector, the TCP
being the flange) the forward kinematics of ``actual_q`` (with no jitter: the
world's pose itself), ``actual_qd`` the difference of consecutive
``actual_q`` over their time, ``actual_TCP_force`` the world's contact wrench
with a UR5e's error (``simworld.robot_wrench``: the force in Base, the moment
about the TCP). ``target_q``/``target_qd``/
``target_TCP_pose`` equal the actual values, ``robot_mode`` is 7 (running),
``safety_mode`` 1 (normal), ``runtime_state`` 1 (stopped: no program), input
registers read back what clients wrote; every other known output is a
constant of its type (0).

**Following** (a world whose motion is ``servo``, ``SimWorld.live``): the
controller runs ``hapticlab_follow.script`` as the real one would
(``ur_follow.py``): at each cycle a new sequence number in
``input_int_register_21`` sends the world's robot to the target in registers
18–20 (``servo_cp``), ``output_int_register_21`` echoes the number applied,
``runtime_state`` is 2 (playing), and with no new number for ``WATCHDOG_S`` the
arm stops where it is. Packages go out in bursts about once a millisecond,
every one whose cycle has come (none is dropped when the scheduler is late).

Run it as ``hapticlab emulate ur --address 127.0.0.x`` (:func:`add_arguments`,
:func:`run`; the host gives it the session's world) or from Python::

    with UREmulator(world, address="127.0.0.31", model="ur5e") as emu:
        ...  # a client in another process: ur-rtde's RTDEReceiveInterface("127.0.0.31")
        emu.inputs()["input_double_register_18"]

ur-rtde's constructors hold the GIL while they wait for the controller's
answers, so a ur-rtde client in the emulator's own process waits forever: run
the two in different processes (the emulator's threads need the GIL to answer).
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from typing import Any

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.frames import matrix_from_quat_wxyz, quat_from_rotvec, quat_wxyz_from_matrix, rotvec_from_quat
from hapticlab.core.host.options import OptionError, choice, number, vector
from hapticlab.core.types import EmulatorCommand
from hapticlab.plugins.kinematics.rtde_protocol import INFO, RTDE_PORT, WARNING, pack_text_message
from hapticlab.plugins.kinematics.rtde_server import RTDEServer
from hapticlab.plugins.kinematics.sim import ENCODER_STREAM
from hapticlab.plugins.kinematics.ur_arm import UR_DH, URArm
from hapticlab.plugins.kinematics.ur_follow import (
    POSITION_REGISTERS,
    ROTATION_REGISTERS,
    SEQUENCE_REGISTER,
    WATCHDOG_S,
    decode_target,
)
from hapticlab.plugins.serving import serve_until_stopped
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.plugins.simworld.randomness import gaussian_noise
from hapticlab.plugins.simworld.robot_wrench import RobotWrench

CONTROLLER_VERSIONS = {False: (5, 15, 0, 0), True: (3, 15, 8, 0)}
"""Controller version reported: e-Series (False) or CB3 (True)."""
CYCLE_HZ = {False: 500.0, True: 125.0}
"""Controller cycle rate (the highest RTDE frequency), Hz: e-Series (False) or CB3 (True)."""

ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
RUNTIME_STATE_STOPPED = 1
RUNTIME_STATE_PLAYING = 2


class UREmulator:
    """A UR controller's RTDE server (port 30004) on a loopback address, fed by a SimWorld.

    Parameters
    ----------
    world : the simulated world whose flange pose (``world.pose(t)``, Base frame) the arm follows.
    address : IPv4 address to listen on (a distinct 127.0.0.x per emulator: ur-rtde always uses port 30004).
    model : a key of ``ur_arm.UR_DH``; ``ur3``/``ur5``/``ur10`` are CB3 (3.x controller, 125 Hz cycle),
        the others e-Series (5.x, 500 Hz).
    port : TCP port (30004 for ur-rtde; 0 picks a free one, for raw-protocol clients).
    encoder_noise : standard deviation of each joint's reading around the true joint angle, rad. A real
        arm's encoders jitter, so its reported pose is never bit-identical from one cycle to the next (the
        session's frozen-pose watch relies on that); ``actual_TCP_pose`` is then the forward kinematics of
        the jittered joints, as the controller computes it. 0: the world's exact pose.
    tcp_offset : the TCP set in the robot's installation, as the controller takes it: (6,) position
        p_EoTo_E (m) and rotation vector of R_ET (rad) of the TCP T in the flange E. ``actual_TCP_pose`` is
        then T's pose, not the flange's (what a lab must avoid: hapticlab needs the flange).
    stalls : windows ``(start, duration)`` of world time, s, in which the controller sends no data package
        while every connection stays open (a stalled stream: a busy controller, a switch holding frames);
        the packages due then are never sent (counted in :attr:`packages_stalled`), and the stream resumes
        at the current cycle, so a client sees the timestamp jump.
    """

    def __init__(
        self,
        world: SimWorld,
        address: str = "127.0.0.1",
        model: str = "ur5e",
        port: int = RTDE_PORT,
        encoder_noise: float = 1e-7,
        tcp_offset: tuple[float, ...] = (0.0,) * 6,
        stalls: tuple[tuple[float, float], ...] | list[tuple[float, float]] = (),
    ):
        choice("model", model, list(UR_DH))
        self.world = world
        self.address = address
        self.arm = URArm(model)
        self.model = model
        self.cb3 = self.arm.cb3
        self.cycle_hz = CYCLE_HZ[self.cb3]
        self.controller_version = CONTROLLER_VERSIONS[self.cb3]
        q0 = self.arm.inverse_nearest(*[x[0] for x in world.pose(0.0)])
        if q0 is None:
            p = world.pose(0.0)[1][0]
            raise OptionError(
                "model",
                f"must reach the world's flange position {np.round(p, 3).tolist()} m at t = 0, got {model!r}; "
                f"give the world's motion a p_BoEo_B within reach",
            )
        self._q, self._q_reported, self._q_t = q0, q0, 0.0
        self.encoder_noise = number("encoder_noise", encoder_noise, minimum=0, maximum=1e-3, hint=" rad")
        tcp = vector("tcp_offset", tcp_offset, size=6, hint=" (x, y, z in m, rotation vector in rad)")
        self.p_EoTo_E, self.R_ET = tcp[:3], matrix_from_quat_wxyz(quat_from_rotvec(tcp[3:])[None])[0]
        self.stalls = tuple(
            (
                number("stalls", start, minimum=0, hint=" s (a stall's start)"),
                number("stalls", duration, above=0, finite=False, hint=" s (a stall's duration)"),
            )
            for start, duration in stalls
        )
        self.packages_stalled = 0
        """Data packages not sent because they fell in a stall."""
        self._noise_key = int(
            np.random.SeedSequence(world.seed, spawn_key=(ENCODER_STREAM,)).generate_state(1, np.uint64)[0]
        )
        self.robot_wrench = RobotWrench(world)
        """``actual_TCP_force``: the world's contact wrench with a UR5e's error (``simworld.robot_wrench``)."""
        self._qd = np.zeros(6)
        self._unreachable_reported = False
        self._server = RTDEServer(address, port, self.cycle_hz, self.controller_version, lambda: self._cycle)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.t0_ns: int | None = None
        """The controller's start (``timestamp`` 0, the world's time 0) on the monotonic clock, ns."""
        self._cycle = 0
        self.follows = world.live
        """The controller runs the follow script: the world's robot goes to the targets written to the registers."""
        self.targets_applied = 0
        """Targets the follow script took from the registers."""
        self.watchdog_stops = 0
        """Times the follow script stopped the arm because targets stopped coming."""
        self._sequence_applied = 0
        self._sequence_cycle = -1  # the cycle the last new sequence number came at
        self._stopped = True

    # ------------------------------------------------------------------ life cycle

    def start(self, t0_ns: int | None = None) -> UREmulator:
        """Listen, and start the controller clock; a second call does nothing.

        ``t0_ns`` is the controller's ``timestamp`` 0 (the world's time 0) on the
        monotonic clock (``time.monotonic_ns``), e.g. another emulator's start so
        both follow one world time; None: now.
        """
        if self._server.listening:
            return self
        self._server.listen()
        self._stop.clear()
        self.t0_ns = time.monotonic_ns() if t0_ns is None else int(t0_ns)
        self._thread = threading.Thread(target=self._controller_loop, name="ur-emulator _controller_loop", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Close every connection and the listening socket (a client sees the controller gone)."""
        self._stop.set()
        self._server.close()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> UREmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> int:
        """The TCP port it listens on (the one the kernel picked, after ``start`` with port 0)."""
        return self._server.port

    def inputs(self) -> dict[str, Any]:
        """The input fields clients have written (register name → last value)."""
        return self._server.inputs()

    @property
    def clients(self) -> int:
        """Clients connected now."""
        return self._server.clients

    @property
    def messages(self) -> list[str]:
        """Text messages clients sent, oldest first."""
        return self._server.messages

    @property
    def packages_sent(self) -> int:
        """Data packages sent to clients since start."""
        return self._server.packages_sent

    # ------------------------------------------------------------------ the robot

    def state(self, cycle: int) -> dict[str, Any]:
        """The controller's outputs at ``cycle`` (cycles are ``1/cycle_hz`` s apart from start).

        Called in cycle order; q follows the continuous IK branch from the previous call.
        """
        t = cycle / self.cycle_hz
        R_BE, p_BoEo_B = (x[0] for x in self.world.pose(t))
        q = self.arm.inverse_nearest(R_BE, p_BoEo_B, self._q)
        if q is None:  # out of reach: hold the joints, say so once
            q = self._q
            if not self._unreachable_reported:
                self._unreachable_reported = True
                self._server.broadcast(
                    pack_text_message(
                        f"flange pose {np.round(p_BoEo_B, 3).tolist()} m at t = {t:.3f} s "
                        f"is out of the {self.model}'s reach; joints held",
                        level=WARNING,
                    )
                )
        self._q = q  # the continuous branch follows the true joints
        if self.encoder_noise > 0:  # the encoders' reading, and the controller's FK of it
            t_ns = np.array([round(t * 1e9)], dtype=np.int64)
            q = q + self.encoder_noise * gaussian_noise(self._noise_key, t_ns, 6)[0]
            R_BE, p_BoEo_B = self.arm.forward(q)
        if t > self._q_t:
            self._qd = (q - self._q_reported) / (t - self._q_t)
        self._q_reported, self._q_t = q, t
        wrench_B = self.robot_wrench.measured(np.array([t]), np.array([round(t * 1e9)], dtype=np.int64))[0]
        wrench_B[3:] -= np.cross(R_BE @ self.p_EoTo_E, wrench_B[:3])  # the moment about the TCP, not E
        p_BoEo_B, R_BE = p_BoEo_B + R_BE @ self.p_EoTo_E, R_BE @ self.R_ET  # the TCP's pose (E's when no offset)
        pose = tuple(np.concatenate([p_BoEo_B, rotvec_from_quat(quat_wxyz_from_matrix(R_BE))]).tolist())
        q_t, qd_t = tuple(q.tolist()), tuple(self._qd.tolist())
        return {
            "timestamp": t,
            "actual_q": q_t,
            "actual_qd": qd_t,
            "target_q": q_t,
            "target_qd": qd_t,
            "actual_TCP_pose": pose,
            "actual_TCP_force": tuple(wrench_B.tolist()),
            "target_TCP_pose": pose,
            "robot_mode": ROBOT_MODE_RUNNING,
            "safety_mode": SAFETY_MODE_NORMAL,
            "safety_status": SAFETY_MODE_NORMAL,
            "runtime_state": RUNTIME_STATE_PLAYING if self.follows else RUNTIME_STATE_STOPPED,
            f"output_int_register_{SEQUENCE_REGISTER}": self._sequence_applied,
            "speed_scaling": 1.0,
            "target_speed_fraction": 1.0,
            "speed_scaling_combined": 1.0,
            "joint_mode": (255,) * 6,
        }

    def _follow(self, cycle: int) -> None:
        """The follow script's cycle: a new target in the registers goes to the world's robot; none for
        ``WATCHDOG_S`` stops it where it is."""
        inputs = self._server.inputs()
        t = cycle / self.cycle_hz
        sequence = int(inputs.get(f"input_int_register_{SEQUENCE_REGISTER}", 0))
        if sequence not in (0, self._sequence_applied):
            R_BE, p_BoEo_B = decode_target(
                [inputs.get(f"input_double_register_{r}", 0.0) for r in POSITION_REGISTERS],
                [inputs.get(f"input_int_register_{r}", 0) for r in ROTATION_REGISTERS],
            )
            try:
                self.world.servo_cp(t, R_BE, p_BoEo_B)
            except ValueError as exc:  # a non-finite target: the script's get_inverse_kin would fail; keep the last
                self._server.broadcast(pack_text_message(f"hapticlab_follow: target refused: {exc}", level=WARNING))
                return
            self._sequence_applied, self._sequence_cycle, self._stopped = sequence, cycle, False
            self.targets_applied += 1
        elif not self._stopped and (cycle - self._sequence_cycle) / self.cycle_hz > WATCHDOG_S:
            R_BE, p_BoEo_B = (x[0] for x in self.world.pose(t))  # stopj: stop where it is
            self.world.servo_cp(t, R_BE, p_BoEo_B)
            self._stopped = True
            self.watchdog_stops += 1
            self._server.broadcast(pack_text_message("hapticlab_follow: no target for 100 ms, stopped", level=INFO))

    def _controller_loop(self) -> None:
        """Every cycle whose time has come: send the packages due (bursts about once a millisecond)."""
        while not self._stop.is_set():
            due = math.floor((time.monotonic_ns() - self.t0_ns) * self.cycle_hz / 1e9)  # type: ignore[operator]  # started: t0_ns is set
            while self._cycle <= due and not self._stop.is_set():
                if self.follows:
                    self._follow(self._cycle)
                self._serve_cycle(self._cycle)
                self._cycle += 1
            self._stop.wait(0.001)

    def _serve_cycle(self, cycle: int) -> None:
        t = cycle / self.cycle_hz
        stalled = any(start <= t < start + duration for start, duration in self.stalls)  # nothing goes out
        self.packages_stalled += self._server.serve_cycle(cycle, self.state, stalled)


# ---------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate ur`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument(
        "--address",
        default="127.0.0.1",
        help="IPv4 address to serve RTDE on, port 30004 (default 127.0.0.1); a loopback one (127.0.0.x) only: "
        "another address of this machine (0.0.0.0: all of them) serves the network, with --allow-network",
    )
    parser.add_argument(
        "--model",
        default="ur5e",
        choices=list(UR_DH),
        help="UR model: its DH geometry; ur3/ur5/ur10 are CB3 (3.x controller, 125 Hz), "
        "the others e-Series (5.x, 500 Hz) (default ur5e)",
    )
    parser.add_argument(
        "--encoder-noise",
        type=float,
        default=1e-7,
        help="std of each joint reading around the true angle, rad (0: the world's exact pose; default 1e-7)",
    )
    parser.add_argument(
        "--tcp-offset",
        default="0,0,0,0,0,0",
        metavar="X,Y,Z,RX,RY,RZ",
        help="the installation's TCP in the flange (m, rotation vector in rad): actual_TCP_pose "
        "is then that point's pose (default: none, the flange)",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")


def run(args: argparse.Namespace, world: SimWorld) -> int:
    """Serve RTDE, the arm moved by ``world``, until Ctrl-C, SIGTERM or ``--duration``; the first line printed
    names the address. Exit status 0."""
    try:
        try:
            tcp_offset = tuple(float(x) for x in args.tcp_offset.split(","))
        except ValueError:
            raise OptionError("--tcp-offset", f"must be X,Y,Z,RX,RY,RZ (m, rad), got {args.tcp_offset!r}") from None
        emulator = UREmulator(
            world, address=args.address, model=args.model, encoder_noise=args.encoder_noise, tcp_offset=tcp_offset
        )
        emulator.start()
    except ValueError as exc:
        raise ConfigError(f"emulate ur: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"emulate ur: cannot serve on {args.address}:{RTDE_PORT}: {exc.strerror or exc}") from None
    with emulator:
        serve_until_stopped(
            args.duration,
            ready=lambda: print(
                f"UR {args.model} RTDE emulator on {emulator.address}:{emulator.port} "
                f"(controller {'.'.join(map(str, emulator.controller_version))}, {emulator.cycle_hz:g} Hz)",
                flush=True,
            ),
        )
    inputs = emulator.inputs()
    print(
        f"sent {emulator.packages_sent} data packages; {len(inputs)} input field(s) written"
        + (f": {', '.join(sorted(inputs))}" if inputs else ""),
        flush=True,
    )
    return 0


@hookimpl
def register_emulators(register):
    register(
        "ur",
        EmulatorCommand(
            help="Universal Robots controller: RTDE v2 on port 30004 (e-Series 500 Hz, CB3 125 Hz)",
            add_arguments=add_arguments,
            run=run,
            needs_world=True,
            listens_on=("address",),
        ),
    )
