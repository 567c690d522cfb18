"""The simulated robot under a position servo: the flange follows a Cartesian target it is sent.

Every other motion script is a pure function of time. In a teleoperated
session the robot goes where the trainee's hand sends it, so its motion is
only known up to *now*: :class:`ServoedMotion` integrates a servo controller
forward in fixed steps as time advances, with the target held between
commands (``servo_cp``, the CRTK name), and answers ``evaluate(t)`` for any
time it has already integrated (a window of ``history_s``) or, by
integrating further, for a later one. Asking for a time ahead of the last
command integrates with the last target: the simulated devices must not read
ahead of the session's clock (``live`` tells them; they compute ahead only the
part of their readings that depends on the time alone, their noise).

The controller, per step of ``step_s`` (1 ms), for the translation p and the
rotation (error ``e = Log(R_BEᵀ R_BE_target)`` in E) alike, is a critically
damped second-order servo of bandwidth ω = 2π·``bandwidth_hz``::

    a = ω² (p_target − p) − 2 ω v,     |a| ≤ max_accel,  |v + a·dt| ≤ max_speed
    α = ω² e − 2 ω w_E,                |α| ≤ max_angular_accel, |w_E + α·dt| ≤ max_angular_speed

with the acceleration held over the step, so that within step k (τ = t − t_k)::

    p(t) = p_k + v_k τ + ½ a_k τ²,   v(t) = v_k + a_k τ,   a(t) = a_k
    R_BE(t) = R_k Exp(w_k τ + ½ α_k τ²),   w_E(t) = w_k + α_k τ,   α_E(t) = α_k

which is what the simulated sensor's inertial wrench and the kinematics read
(exact for the translation; for the rotation ``w_E`` is the derivative of the
orientation to first order in the step's angle). A position-controlled arm
(a UR in ``servoj``/``servol``) is stiff: contact forces do not push it off
its path, so the tissue's reaction does not enter the controller.

Frames: B robot base, E flange. ``R_BE`` maps vectors from E into B.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence

import numpy as np

from hapticlab.core.frames import skew_stack
from hapticlab.core.host.options import OptionError, number
from hapticlab.plugins.simworld import servo_kernel as servo_kernel
from hapticlab.plugins.simworld.motion import DEFAULT_P_BoEo_B, Hold, MotionScript, MotionState

__all__ = ["ServoedMotion"]


# The integrator runs one step per millisecond inside the live loop's reads: plain floats
# (3-vectors as tuples, 3x3 matrices as 9-tuples, row-major) cost a fraction of numpy's
# per-call overhead on arrays this small.


def _matmul(A, B):
    """A·B for 3x3 matrices as row-major 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = A
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = B
    return (
        a0 * b0 + a1 * b3 + a2 * b6,
        a0 * b1 + a1 * b4 + a2 * b7,
        a0 * b2 + a1 * b5 + a2 * b8,
        a3 * b0 + a4 * b3 + a5 * b6,
        a3 * b1 + a4 * b4 + a5 * b7,
        a3 * b2 + a4 * b5 + a5 * b8,
        a6 * b0 + a7 * b3 + a8 * b6,
        a6 * b1 + a7 * b4 + a8 * b7,
        a6 * b2 + a7 * b5 + a8 * b8,
    )


def _transpose_matmul(A, B):
    """Aᵀ·B for 3x3 matrices as row-major 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = A
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = B
    return (
        a0 * b0 + a3 * b3 + a6 * b6,
        a0 * b1 + a3 * b4 + a6 * b7,
        a0 * b2 + a3 * b5 + a6 * b8,
        a1 * b0 + a4 * b3 + a7 * b6,
        a1 * b1 + a4 * b4 + a7 * b7,
        a1 * b2 + a4 * b5 + a7 * b8,
        a2 * b0 + a5 * b3 + a8 * b6,
        a2 * b1 + a5 * b4 + a8 * b7,
        a2 * b2 + a5 * b5 + a8 * b8,
    )


def _exp(x, y, z):
    """The rotation matrix (row-major 9-tuple) of the rotation vector (x, y, z), rad (Rodrigues)."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return (1.0, -z, y, z, 1.0, -x, -y, x, 1.0)
    s, c = math.sin(angle) / angle, (1.0 - math.cos(angle)) / (angle * angle)
    return (
        1.0 - c * (y * y + z * z),
        -s * z + c * x * y,
        s * y + c * x * z,
        s * z + c * x * y,
        1.0 - c * (x * x + z * z),
        -s * x + c * y * z,
        -s * y + c * x * z,
        s * x + c * y * z,
        1.0 - c * (x * x + y * y),
    )


def _log(R):
    """The rotation vector (rad) of a rotation matrix (row-major 9-tuple), angles below π."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = R
    angle = math.acos(min(max((r0 + r4 + r8 - 1.0) * 0.5, -1.0), 1.0))
    k = 0.5 if angle < 1e-6 else 0.5 * angle / math.sin(angle)
    return (k * (r7 - r5), k * (r2 - r6), k * (r3 - r1))


def _limited(x, y, z, limit):
    """(x, y, z) with its norm cut to ``limit``, direction kept."""
    norm = math.sqrt(x * x + y * y + z * z)
    if norm <= limit:
        return x, y, z
    k = limit / norm
    return x * k, y * k, z * k


def _servo_accel(err, vel, omega, dt, max_accel, max_speed):
    """The acceleration over one step of a critically damped servo: error ``err``, velocity ``vel``
    (3-tuples), bandwidth ``omega`` (rad/s), its acceleration and the velocity it reaches limited."""
    w2, d = omega * omega, 2.0 * omega
    ax, ay, az = _limited(w2 * err[0] - d * vel[0], w2 * err[1] - d * vel[1], w2 * err[2] - d * vel[2], max_accel)
    vx, vy, vz = _limited(vel[0] + ax * dt, vel[1] + ay * dt, vel[2] + az * dt, max_speed)
    return ((vx - vel[0]) / dt, (vy - vel[1]) / dt, (vz - vel[2]) / dt)


class ServoedMotion(MotionScript):
    """The flange under a Cartesian position servo, following targets sent while the session runs.

    Parameters
    ----------
    tilt_deg, tilt_axis_B, roll_deg : the start orientation, as :class:`Hold` takes it.
    p_BoEo_B : (3,) the start position of the flange in B, m (the first target too).
    bandwidth_hz : the servo's bandwidth, Hz (critically damped; a step settles in ~1/bandwidth s).
    max_speed : the flange's speed limit, m/s (UR: 0.25 m/s is the collaborative default).
    max_accel : the flange's acceleration limit, m/s².
    max_angular_speed : the flange's turn rate limit, rad/s.
    max_angular_accel : the flange's angular acceleration limit, rad/s².
    step_s : the integration step, s (a UR controller's 2 ms at e-Series is 500 Hz; 1 ms here).
    history_s : how far back ``evaluate`` can look, s (older times get the oldest state kept).

    Attributes:
        live: True: the motion is only known up to the last integrated time (no prefetching).
        target: ``(R_BE (3, 3), p_BoEo_B (3,) m)`` the servo is following.
    """

    name = "servo"
    live = True

    def __init__(
        self,
        tilt_deg: float = 0.0,
        tilt_axis_B: Sequence[float] = (1.0, 0.0, 0.0),
        roll_deg: float = 0.0,
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
        bandwidth_hz: float = 8.0,
        max_speed: float = 0.25,
        max_accel: float = 2.5,
        max_angular_speed: float = 1.0,
        max_angular_accel: float = 10.0,
        step_s: float = 0.001,
        history_s: float = 10.0,
    ):
        for name, value in (
            ("bandwidth_hz", bandwidth_hz),
            ("max_speed", max_speed),
            ("max_accel", max_accel),
            ("max_angular_speed", max_angular_speed),
            ("max_angular_accel", max_angular_accel),
            ("step_s", step_s),
            ("history_s", history_s),
        ):
            number(name, value, above=0)
        if step_s > 0.01 or bandwidth_hz * step_s > 0.05:
            raise OptionError(
                "step_s",
                f"must be <= 0.01 s and <= 1/20 of the servo's period (bandwidth_hz · step_s <= 0.05), "
                f"got {step_s!r} with bandwidth_hz = {bandwidth_hz!r}",
            )
        start = Hold(tilt_deg, tilt_axis_B, roll_deg, p_BoEo_B)
        self.omega = 2.0 * math.pi * bandwidth_hz
        self.max_speed, self.max_accel = float(max_speed), float(max_accel)
        self.max_angular_speed, self.max_angular_accel = float(max_angular_speed), float(max_angular_accel)
        self.dt = float(step_s)
        self.target = (start.R_BE.copy(), start.p_BoEo_B.copy())
        self._target = (tuple(start.R_BE.ravel().tolist()), tuple(start.p_BoEo_B.tolist()))
        self._lock = threading.Lock()
        self._size = math.ceil(history_s / step_s) + 1
        self._history = np.zeros((self._size, 24))
        """Row k % size: step k's state, [p (3) m, v (3) m/s, a (3) m/s², R_BE (9, row-major),
        w_E (3) rad/s, α_E (3) rad/s²]; the newest is also kept as floats in ``_state``."""
        zero = (0.0, 0.0, 0.0)
        self._k = 0
        self._last: tuple[int, bytes, MotionState] | None = None
        """The last ``evaluate``: (the newest step then, the times' bytes, the state)."""
        self._state = [tuple(start.p_BoEo_B.tolist()), zero, zero, tuple(start.R_BE.ravel().tolist()), zero, zero]
        self._controls()
        servo_kernel.warm_up()  # compiled (or loaded from the cache) before the first live tick

    # ------------------------------------------------------------------ commands

    def servo_cp(self, t: float, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> None:
        """From world time ``t`` (s) on, follow the flange pose ``R_BE`` (3, 3), ``p_BoEo_B`` (3,) m.

        The motion up to ``t`` is integrated first with the previous target
        (what was commanded stays the past's); a non-finite target is refused
        with ValueError (the robot keeps its last one).
        """
        R_BE = np.asarray(R_BE, dtype=float)
        p_BoEo_B = np.asarray(p_BoEo_B, dtype=float)
        shaped = R_BE.shape == (3, 3) and p_BoEo_B.shape == (3,)
        target = (tuple(R_BE.ravel().tolist()), tuple(p_BoEo_B.tolist())) if shaped else ((), ())  # (floats)
        if not shaped or not all(map(math.isfinite, target[0] + target[1])):
            raise ValueError(f"servo_cp: need a finite (3, 3) R_BE and (3,) p_BoEo_B, got {R_BE!r}, {p_BoEo_B!r}")
        with self._lock:
            self._advance(t)
            self.target = (R_BE.copy(), p_BoEo_B.copy())
            self._target = target

    # ------------------------------------------------------------------ integration

    def _controls(self) -> None:
        """The newest step's accelerations from its state and the target; its history row written."""
        p, v, _, R, w, _ = self._state
        R_target, p_target = self._target
        a = _servo_accel(
            (p_target[0] - p[0], p_target[1] - p[1], p_target[2] - p[2]),
            v,
            self.omega,
            self.dt,
            self.max_accel,
            self.max_speed,
        )
        alpha = _servo_accel(
            _log(_transpose_matmul(R, R_target)), w, self.omega, self.dt, self.max_angular_accel, self.max_angular_speed
        )
        self._state[2], self._state[5] = a, alpha
        self._history[self._k % self._size] = (*p, *v, *a, *R, *w, *alpha)

    def _advance(self, t: float) -> None:
        """Integrate step by step until the newest step's interval holds ``t``."""
        last = math.floor(t / self.dt + 1e-9)
        dt = self.dt
        half_dt2 = 0.5 * dt * dt
        while self._k < last:
            p, v, a, R, w, alpha = self._state
            self._state = [
                (
                    p[0] + v[0] * dt + a[0] * half_dt2,
                    p[1] + v[1] * dt + a[1] * half_dt2,
                    p[2] + v[2] * dt + a[2] * half_dt2,
                ),
                (v[0] + a[0] * dt, v[1] + a[1] * dt, v[2] + a[2] * dt),
                a,
                _matmul(
                    R,
                    _exp(
                        w[0] * dt + alpha[0] * half_dt2,
                        w[1] * dt + alpha[1] * half_dt2,
                        w[2] * dt + alpha[2] * half_dt2,
                    ),
                ),
                (w[0] + alpha[0] * dt, w[1] + alpha[1] * dt, w[2] + alpha[2] * dt),
                alpha,
            ]
            self._k += 1
            self._controls()

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        """The flange pose and its derivatives at times ``t`` (s), integrating up to the latest asked for.

        The same times asked for again with no step integrated since (the sensor, the kinematics and
        the robot's wrench of one tick) get the same state back, not recomputed: its arrays are shared,
        to be read, never written.

        Within a step the rotation is ``R_k (I + [φ]× + ½[φ]×²)`` with φ = w_k τ + ½ α_k τ²:
        Exp to second order, off by |φ|³/6 (2·10⁻¹⁰ at 1 rad/s and 1 ms steps). Compiled
        (``plugins.simworld.servo_kernel``: the live loop asks one sample at a time); :meth:`evaluate_reference`
        is the same in numpy.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
        n = len(t)
        key = t.tobytes()
        with self._lock:
            if n:
                self._advance(float(t.max()))
            if self._last is not None and self._last[0] == self._k and self._last[1] == key:
                return self._last[2]
            R_BE = np.empty((n, 3, 3))
            p, v, a, w, alpha = (np.empty((n, 3)) for _ in range(5))
            servo_kernel.evaluate(
                self._history, t, self.dt, max(self._k - self._size + 1, 0), self._k, R_BE, p, v, a, w, alpha
            )
            state = MotionState(t=t, R_BE=R_BE, p_BoEo_B=p, w_BE_E=w, alpha_BE_E=alpha, v_BEo_B=v, a_BEo_B=a)
            self._last = (self._k, key, state)
        return state

    def evaluate_reference(self, t: float | np.ndarray) -> MotionState:
        """:meth:`evaluate` in numpy (the reference the tests compare the compiled kernel with)."""
        t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
        with self._lock:
            if len(t):
                self._advance(float(t.max()))
            first = max(self._k - self._size + 1, 0)
            k = np.minimum(np.maximum(np.floor(t / self.dt + 1e-9).astype(np.int64), first), self._k)
            rows = self._history[k % self._size]
        tau = np.maximum(t - k * self.dt, 0.0)[:, None]
        p, v, a = rows[:, 0:3], rows[:, 3:6], rows[:, 6:9]
        w, alpha = rows[:, 18:21], rows[:, 21:24]
        phi = w * tau + 0.5 * alpha * tau * tau
        phi_cross = skew_stack(phi)
        R_k = rows[:, 9:18].reshape(-1, 3, 3)
        return MotionState(
            t=t,
            R_BE=R_k + R_k @ (phi_cross + 0.5 * (phi_cross @ phi_cross)),
            p_BoEo_B=p + v * tau + 0.5 * a * tau * tau,
            w_BE_E=w + alpha * tau,
            alpha_BE_E=alpha.copy(),
            v_BEo_B=v + a * tau,
            a_BEo_B=a.copy(),
        )
