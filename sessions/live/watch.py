"""Watches on the live streams that timestamps alone cannot give: frozen poses, late poses, steps and a stuck sensor.

:class:`PoseWatch`: a real arm's reported pose is never bit-identical from one
sample to the next (its encoders jitter); a controller whose thread is stuck
keeps sending the last pose with fresh timestamps. Poses that have not changed
for longer than ``frozen_pose_timeout`` are frozen kinematics. Two
consecutive poses further apart than the arm can move between their stamps
(``max_turn_rate``, ``max_speed``) are a jump: a stream that fell behind or
caught up at once, or a glitch.

:class:`StepWatch`: a contact is a force between the tool and the world; it grows as the tool presses
in, so it cannot jump tens of newtons between two samples. A reading that moves further from the
last one than ``MAX_CONTACT_RATE`` allows (plus ``STEP_MARGIN_N`` of noise) is a glitch of the sensor
or its wire, in range and with a good status all the same: its samples are held out until the reading
is back where it was before the jump; one that stays away for ``STEP_PERSIST_NS`` is handed back to the gate
(a knock, or something the motion has to tell).
A step faster than soft tissue pushes (``SUDDEN_RATE``) but within a contact's is *sudden*: a hard
contact (bone, another instrument) or the sensor's zero moving; the watch says so (``sudden``) and the
gate holds the force until the motion tells which (``drift.DriftWatch``).

:class:`StuckWatch`: a working sensor's readings are never bit-identical for long, its noise sees to
that; a converter or a firmware buffer that froze repeats one reading with fresh stamps and a good status.
"""

from __future__ import annotations

import math

import numpy as np

from hapticlab.core.types import AlignedSamples, PoseSample
from hapticlab.sessions.live.watch_kernel import lag_sums
from hapticlab.sessions.live.watch_kernel import warm_up as warm_up_lag


class PoseWatch:
    """Tells frozen kinematics from a robot that merely stands still, and a pose stream that jumps.

    Args:
        timeout_ns: how long identical poses are accepted, ns.
        max_turn_rate: fastest turn of the tool between two poses, rad/s.
        max_speed: fastest motion of the tool between two poses, m/s.
    """

    def __init__(self, timeout_ns: int, max_turn_rate: float, max_speed: float):
        self.timeout_ns = timeout_ns
        self.max_turn_rate, self.max_speed = max_turn_rate, max_speed
        self.last: tuple[bytes, bytes] | None = None
        self.changed_ns: int | None = None  # stamp of the last pose that differed from its predecessor
        self.newest_ns: int | None = None
        self.previous: tuple[int, list[float], list[float] | None] | None = None  # (t_ns, quat_BE, p_BoEo_B)
        self.jump: tuple[int, str] | None = None  # (stamp, what) of the last jump seen

    def add(self, poses: list[PoseSample], now_ns: int) -> bool:
        """Take the newest poses, read at ``now_ns`` (the session clock); True when they jumped (``jump``
        then says when, on the session clock, and how far). A non-finite pose is a jump too, and never the
        pose the next one is compared with. (Per pose, in Python floats: a few poses a tick, where numpy's
        per-call overhead would cost more than the arithmetic.)"""
        jumped = False
        for pose in poses:
            key = (pose.quat_BE.tobytes(), b"" if pose.p_BoEo_B is None else pose.p_BoEo_B.tobytes())
            if key != self.last:
                self.last, self.changed_ns = key, pose.t_ns
            self.newest_ns = pose.t_ns
            quat = pose.quat_BE.tolist()
            p = None if pose.p_BoEo_B is None else pose.p_BoEo_B.tolist()
            if not (all(map(math.isfinite, quat)) and (p is None or all(map(math.isfinite, p)))):
                self.jump, jumped = (now_ns, "a non-finite pose"), True
                continue
            current = (pose.t_ns, quat, p)
            what = self._jump(self.previous, current) if self.previous is not None else ""
            if what:
                self.jump, jumped = (now_ns, what), True
            self.previous = current
        return jumped

    def _jump(self, a: tuple, b: tuple) -> str:
        """How two consecutive poses (t_ns, quat_BE, p_BoEo_B) moved faster than the arm can ("" when they
        did not)."""
        dt = (b[0] - a[0]) * 1e-9
        if dt <= 0:
            return ""
        # the angle between two unit quaternions: 2·acos|⟨a, b⟩|
        qa, qb = a[1], b[1]
        angle = 2.0 * math.acos(min(1.0, abs(qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2] + qa[3] * qb[3])))
        if angle > self.max_turn_rate * dt:
            return f"turned {angle:.3g} rad in {dt * 1e3:.3g} ms"
        if a[2] is not None and b[2] is not None:
            distance = math.dist(a[2], b[2])
            if distance > self.max_speed * dt:
                return f"moved {distance * 1e3:.3g} mm in {dt * 1e3:.3g} ms"
        return ""

    @property
    def frozen_for_ns(self) -> int:
        """How long the robot has reported the same pose beyond the timeout (0 when it has not), ns."""
        if self.changed_ns is None:
            return 0
        assert self.newest_ns is not None  # add() sets it with changed_ns
        held = self.newest_ns - self.changed_ns
        return held if held > self.timeout_ns else 0


_EYE = np.eye(3)

LAG_LIMIT_S = 0.05
"""Kinematics this far out of step with the sensor (either way) zero the force, s."""
LAG_MEMORY_S = 0.25
"""The lag estimate forgets with this time constant, s."""
LAG_MAX_S = 0.5
"""The largest lag the watch explains; a bigger residual is a contact, s."""
LAG_CONTACT_GUARD_NS = 500_000_000
"""Samples this soon after a contact are left out of the estimate (a contact ramps down below the
estimator's threshold before it ends), ns."""
LAG_MIN_EXPLAINED = 0.5
"""The lag must explain this share of the residual's sum of squares before it is believed."""
LAG_MIN_RESOLUTION_S = 0.01
"""The estimate is trusted once its standard error (noise / √Σ‖ġ‖²) is below this, s."""


class LagWatch:
    """Estimates how far the poses are out of step with the wrench, from the residual's correlation with motion.

    If the poses the robot reports are τ late, the sensor sees the weight where
    the model puts it τ later: the residual is r ≈ τ·ġ_S, with g_S = R_SB·g_B
    the predicted weight in S and ġ_S its rate of change. Over the samples no
    lag up to ``LAG_MAX_S`` leaves unexplained (a larger residual is a contact,
    and so is the next ``LAG_CONTACT_GUARD_NS``), τ̂ = Σ r·ġ / Σ ġ·ġ with exponential
    forgetting; its standard error is the noise over √Σ‖ġ‖², so it speaks only
    while the tool turns, and only when the lag explains most of the residual
    (τ̂·Σ r·ġ ≥ ``LAG_MIN_EXPLAINED`` of Σ‖r‖²): the tail of a contact that
    happens to follow the motion for a moment explains little of its residual. A timestamp cannot
    show this (the poses are stamped as current), a still tool cannot either (then nothing is wrong).

    Args:
        max_turn_rate: faster apparent turns (a pose stream that jumps) are left out of the estimate, rad/s
            (the session's ``max_turn_rate``, the jump rule's limit).
        noise_N: the sensor's force noise per axis, N (for the standard error).
    """

    def __init__(self, max_turn_rate: float, noise_N: float = 0.12):
        self.max_turn_rate = max_turn_rate
        self.noise = noise_N
        warm_up_lag()
        self.reset()

    def reset(self) -> None:
        """Forget what was learnt (the poses jumped: what came before says nothing of what follows)."""
        self.sums = np.zeros(
            6
        )  # S_rg, S_gg, S_rr, and the last sample's predicted weight in S (sessions.live.watch_kernel)
        # the last sample's and the last contact's t_ns, then the bits HAS_LAST | HAS_CONTACT
        # of sessions.live.watch_kernel
        self.clock = np.zeros(3, dtype=np.int64)
        self.lag_s: float | None = None

    def add(self, block: AlignedSamples, params: dict[str, list[float]], R_SE: np.ndarray | None) -> float | None:
        """The lag estimate after this block (s; positive: poses late), once it is resolved, else None.

        The residual is the block's force less the weight and bias of the estimator's ``params``
        (``gravity_force_B``, ``bias_force_S``), so it can be computed while the samples are kept from
        the estimator (which would otherwise learn the lag into its parameters and hide it). The sums
        are ``sessions.live.watch_kernel.lag_sums`` (compiled); the verdict is here.
        """
        gravity, bias = params["gravity_force_B"], params["bias_force_S"]
        if not (all(map(math.isfinite, gravity)) and all(map(math.isfinite, bias))):
            return self.lag_s  # no weight to predict with: nothing to learn from this block
        gravity_force_B, bias_force_S = np.asarray(gravity, dtype=float), np.asarray(bias, dtype=float)
        lag_sums(
            block.t_ns,
            block.R_EB,
            block.force_S,
            _EYE if R_SE is None else R_SE,
            gravity_force_B,
            bias_force_S,
            self.noise,
            LAG_MAX_S,
            LAG_CONTACT_GUARD_NS,
            self.max_turn_rate,
            LAG_MEMORY_S,
            self.sums,
            self.clock,
        )
        sums = self.sums.tolist()
        if not all(map(math.isfinite, sums)):  # never expected (the kernel skips non-finite terms): start afresh
            lag_s = self.lag_s
            self.reset()
            self.lag_s = lag_s
            return self.lag_s
        S_rg, S_gg, S_rr = sums[:3]
        if S_gg > 0 and self.noise / math.sqrt(S_gg) < LAG_MIN_RESOLUTION_S:
            lag = S_rg / S_gg
            if abs(lag) <= LAG_LIMIT_S or lag * S_rg >= LAG_MIN_EXPLAINED * S_rr:
                self.lag_s = lag
            # else: a residual the lag does not explain (a contact): the verdict stands
        # unresolved (the tool barely turns: a lag would do no harm yet): the verdict stands
        return self.lag_s


MAX_CONTACT_RATE = 2000.0
"""The fastest a contact force changes, N/s: a tool striking bone at 0.1 m/s with a contact stiffness of
2·10⁴ N/m (soft tissue is 10²-10³ N/m). A reading faster than this is no contact's."""
STEP_MARGIN_N = 1.5
"""The sensor's noise on a step between two samples: about nine standard deviations of a Gamma-class
sensor's 0.12 N per sample (the simulated sensor's default), N."""
STEP_RETURN_RATE = 100.0
"""How far a real contact may have moved while a glitch lasted, N/s: the reading is back when it is within
``STEP_MARGIN_N`` plus this times the glitch's age of the reading before the jump (and nearer it than half
the jump)."""
SUDDEN_RATE = 100.0
"""The fastest soft tissue pushes, N/s: 10³ N/m at 0.1 m/s. A step beyond this (plus ``STEP_MARGIN_N``)
between two samples is sudden: a hard contact, or the sensor."""
STEP_PERSIST_NS = 200_000_000
"""A jump that has not come back after this long is a bias step of the sensor, not a glitch, ns."""


class StepWatch:
    """Holds out the samples of a reading that jumped faster than any contact, until it is back.

    ``add`` returns the (N,) mask of samples held out. ``jump`` describes the jump in hand ("" when none);
    ``persisted`` is the jump's size in S, (3,) N, once it has stayed ``STEP_PERSIST_NS`` (then the watch
    starts afresh from the new level: the gate holds the force until the motion tells what it was).
    ``sudden`` describes the last sudden step (faster than ``SUDDEN_RATE``, slower than a jump; its samples
    are not held out) until the gate takes it (sets it to ""). The arithmetic is in Python floats: a live
    block is one to seven samples, where numpy's calls cost ten times more.
    """

    def __init__(self) -> None:
        self.last: tuple[int, list[float]] | None = None  # the newest reading (t_ns, force_S)
        self.level: list[float] | None = None  # the reading before the jump in hand (None: no jump)
        self.jumped_ns, self.jump_N = 0, 0.0
        self.jump = ""
        self.sudden = ""
        self.persisted: np.ndarray | None = None

    def add(self, t_ns: np.ndarray, force_S: np.ndarray) -> np.ndarray:
        held = np.zeros(len(t_ns), dtype=bool)
        times, forces = t_ns.tolist(), force_S.tolist()
        if not times:
            return held
        if self.level is None and self.last is not None and self._within(times, forces):
            self.last = (times[-1], forces[-1])  # the usual block: every step within a contact's
            return held
        for k, (t, f) in enumerate(zip(times, forces)):  # a jump in this block, or one in hand
            if self.level is not None:
                age_s = (t - self.jumped_ns) * 1e-9
                away = math.dist(f, self.level)
                # back: nearer the reading before than the jump took it, within what a contact moves meanwhile
                if away <= min(STEP_MARGIN_N + STEP_RETURN_RATE * age_s, self.jump_N / 2):
                    self.level, self.jump = None, ""
                    if away > STEP_MARGIN_N:  # back, but not all the way: the leftover is a doubt of its own
                        self.sudden = f"{away:.3g} N left when a jump came back"
                elif t - self.jumped_ns >= STEP_PERSIST_NS:
                    self.persisted = np.subtract(f, self.level)
                    self.level, self.jump = None, ""
                else:
                    held[k] = True
            elif self.last is not None:
                step, dt_s = math.dist(f, self.last[1]), (t - self.last[0]) * 1e-9
                if step > MAX_CONTACT_RATE * dt_s + STEP_MARGIN_N:
                    self.level, self.jumped_ns, self.jump_N, held[k] = self.last[1], t, step, True
                    self.jump = f"sensor reading jumped {step:.3g} N in {dt_s * 1e3:.3g} ms: faster than a contact"
                elif step > SUDDEN_RATE * dt_s + STEP_MARGIN_N:
                    self.sudden = f"{step:.3g} N in {dt_s * 1e3:.3g} ms"
            if not held[k] or self.last is None:
                self.last = (t, f)
        return held

    def _within(self, times: list[int], forces: list[list[float]]) -> bool:
        """Every step from the newest reading on is within soft tissue's (so within a contact's too)."""
        assert self.last is not None  # (the caller checks)
        t_last, f_last = self.last
        for t, f in zip(times, forces):
            if math.dist(f, f_last) > SUDDEN_RATE * (t - t_last) * 1e-9 + STEP_MARGIN_N:
                return False
            t_last, f_last = t, f
        return True


STUCK_NS = 50_000_000
"""Bit-identical readings (all six axes) for this long, and at least ``STUCK_SAMPLES`` of them, are a stuck
sensor, ns: the real recordings' longest run is 3 samples (logs of 1 s steps), a Net F/T's counts never repeat."""
STUCK_SAMPLES = 5


class StuckWatch:
    """Holds out the readings of a sensor that repeats one reading (``add``: the (N,) mask held out;
    ``stuck_ns``: for how long it has, 0 when it does not). Python floats, as :class:`StepWatch`."""

    def __init__(self) -> None:
        self.last: list[float] | None = None  # the newest reading: force_S then torque_S
        self.since_ns = 0  # the stamp of the run's first reading
        self.count = 0
        self.stuck_ns = 0

    def add(self, t_ns: np.ndarray, force_S: np.ndarray, torque_S: np.ndarray) -> np.ndarray:
        held = np.zeros(len(t_ns), dtype=bool)
        times = t_ns.tolist()
        for k, (t, f, q) in enumerate(zip(times, force_S.tolist(), torque_S.tolist())):
            row = f + q
            if row == self.last:  # (a NaN is never equal: the screen holds those out already)
                self.count += 1
            else:
                self.last, self.since_ns, self.count = row, t, 1
            lasted = t - self.since_ns
            self.stuck_ns = lasted if self.count >= STUCK_SAMPLES and lasted >= STUCK_NS else 0
            held[k] = self.stuck_ns > 0
        return held
