"""The sensor model along a recorded motion, and the interface of effect models.

The discrepancy workflow (``hapticlab.sessions.discrepancy.workflow``) predicts what the
wrist sensor should read at every recorded sample from the robot's motion and
a model, and compares it with what it did read. The model is the paper's base
model plus any number of **effects**, each a physical term with named
parameters, registered by plugins through ``register_effects`` (built-ins in
``hapticlab.plugins.effects``).

The measurement chain, in the order it is evaluated (``STAGES``)::

    timing   which pose belongs to which wrench sample     (time_lag)
    mount    R_SE, the sensor's orientation on the flange   (mount_rotation)
    ---      the tool's weight in S:  F = R_SE R_EB gravity_force_B,  τ = cog_S × F
    load     more true wrench on the sensor                 (inertia)
    sensor   what the sensor makes of the true wrench       (gain_crosstalk)
    ---      + bias_force_S, + bias_torque_S
    bias     a bias that changes                            (bias_drift)

An effect declares its ``stage`` and maps a :class:`ModelState` to a new one
(``apply``); effects of one stage run in the order they were added. With its
``initial()`` parameters an effect must leave the prediction unchanged (it is
"switched off"), so the workflow can test it from the current model.

:class:`Model` stacks the base parameters and the effects' parameters into
one vector, predicts the reading, and gives its Jacobian by finite differences
of ``apply`` (central for effect parameters, with each effect's ``steps``).

Frames and units as everywhere (``hapticlab.core.frames``): ``R_EB`` maps B
into E, forces N, torques N·m, time s (or rows, see :class:`Motion`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

from hapticlab.core.frames import GRAVITY_M_S2, cross, matrix_from_quat_wxyz, quat_conjugate, quat_multiply, quat_slerp

__all__ = ["BASE_LABELS", "STAGES", "Effect", "LocatesItself", "Model", "ModelState", "Motion", "motion_from_poses"]

STAGES = ("timing", "mount", "load", "sensor", "bias")
"""Where an effect acts in the measurement chain, in evaluation order (see the module docstring)."""

BASE_LABELS = (
    "gravity_force_B.x",
    "gravity_force_B.y",
    "gravity_force_B.z",
    "bias_force_S.x",
    "bias_force_S.y",
    "bias_force_S.z",
    "cog_S.x",
    "cog_S.y",
    "cog_S.z",
    "bias_torque_S.x",
    "bias_torque_S.y",
    "bias_torque_S.z",
)
"""The paper's twelve parameters, in the order of the parameter vector's head."""

BASE_STEPS = np.array([1e-4] * 6 + [1e-6] * 3 + [1e-5] * 3)
"""Forward-difference steps of the base parameters (N, N, m, N·m): they enter (nearly) linearly."""


# --------------------------------------------------------------------------- the recorded motion


@dataclass(frozen=True)
class Motion:
    """The recorded motion at each wrench sample: what effects may use.

    Attributes:
        t: (n,) sample times on the sensor's clock: seconds, or row numbers when
            ``time_base`` is ``"index"`` (the file's ``t`` counts rows or poses).
        R_EB: (n, 3, 3) orientation of B in E (from the kinematics).
        quat_BE: (n, 4) the same as [w, x, y, z] quaternions of E in B, sign-continuous.
        w_E: (n, 3) angular velocity of E in B, expressed in E, rad/s; None
            without a time base.
        alpha_E: (n, 3) angular acceleration, rad/s²; None without a time base.
        a_B: (n, 3) acceleration of E's origin in B, m/s² (gravity excluded);
            None without positions or a time base.
        time_base: ``"seconds"`` or ``"index"``.
        rate_hz: samples per second (median), None with an index time base.
        t_ref: reference time of time-varying terms (the middle of the whole recording).
        shift: how far the kinematic quantities were shifted from the recording's, s.
        source: the recorded motion this one was shifted from (None: this is it).
    """

    t: np.ndarray
    R_EB: np.ndarray
    quat_BE: np.ndarray
    w_E: np.ndarray | None = None
    alpha_E: np.ndarray | None = None
    a_B: np.ndarray | None = None
    time_base: str = "seconds"
    rate_hz: float | None = None
    t_ref: float = 0.0
    shift: float = 0.0
    source: Motion | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def has_time(self) -> bool:
        """True when ``t`` is in seconds and the derivatives exist."""
        return self.time_base == "seconds" and self.w_E is not None

    def subset(self, index) -> Motion:
        """The samples selected by a mask or index array (of a recorded motion, not a shifted one)."""
        if self.source is not None:
            raise ValueError("subset() of a shifted motion; take the subset of the recording, then shift")
        pick = lambda a: None if a is None else a[index]  # noqa: E731
        return Motion(
            self.t[index],
            self.R_EB[index],
            self.quat_BE[index],
            pick(self.w_E),
            pick(self.alpha_E),
            pick(self.a_B),
            self.time_base,
            self.rate_hz,
            self.t_ref,
        )

    def shifted(self, dt: float) -> Motion:
        """The motion recorded at ``t + dt`` for each sample (slerp and linear interpolation; held at the ends).

        ``t`` itself is kept (it is the sensor's clock); only the kinematic
        quantities move. Shifts add up, and always interpolate the recording.
        """
        src = self.source if self.source is not None else self
        total = self.shift + float(dt)
        if total == 0.0:
            return src
        t = src.t
        at = np.clip(t + total, t[0], t[-1])
        k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
        span = t[k + 1] - t[k]
        u = np.clip(np.divide(at - t[k], span, out=np.zeros_like(at), where=span > 0), 0.0, 1.0)
        quat = quat_slerp(src.quat_BE[k], src.quat_BE[k + 1], u)
        lerp = lambda a: None if a is None else a[k] + u[:, None] * (a[k + 1] - a[k])  # noqa: E731
        return Motion(
            t,
            matrix_from_quat_wxyz(quat).transpose(0, 2, 1),
            quat,
            lerp(src.w_E),
            lerp(src.alpha_E),
            lerp(src.a_B),
            src.time_base,
            src.rate_hz,
            src.t_ref,
            total,
            src,
        )


def _continuous(quat: np.ndarray) -> np.ndarray:
    """Quaternions with signs flipped so consecutive ones are on the same hemisphere."""
    dots = np.einsum("ij,ij->i", quat[1:], quat[:-1])
    flips = np.concatenate([[False], dots < 0])
    sign = np.where(np.logical_xor.accumulate(flips), -1.0, 1.0)
    return quat * sign[:, None]


def savgol(x: np.ndarray, window: int, deriv: int, dt: float, order: int = 3) -> np.ndarray:
    """Savitzky–Golay smoothing or derivative of (n, k) uniformly sampled columns.

    A least-squares polynomial of ``order`` over ``window`` (odd) samples
    centred on each sample, evaluated (its ``deriv``-th derivative) there; the
    first and last half-windows use the polynomial of the first and last full
    window (scipy's ``mode="interp"``). Plain numpy: scipy's own BLAS threads
    would then contend with numpy's for the two cores here.
    """
    n, half = len(x), window // 2
    s = np.arange(-half, half + 1, dtype=float)
    V = np.vander(s, order + 1, increasing=True)  # (window, order+1): 1, s, s², ...
    fit = np.linalg.pinv(V)  # rows: polynomial coefficients from the window's samples
    scale = float(np.prod(np.arange(1, deriv + 1))) / dt**deriv
    coeff = fit[deriv] * scale  # value of the deriv-th derivative at s = 0
    out = np.empty_like(x, dtype=float)
    # interior: a correlation with the coefficients, column by column
    from numpy.lib.stride_tricks import sliding_window_view

    windows = sliding_window_view(x, window, axis=0)  # (n - window + 1, k, window)
    out[half : n - half] = windows @ coeff
    # the edges: derivative of the first/last window's polynomial at each edge sample
    powers = np.arange(order + 1)
    for rows, block in ((slice(0, half), x[:window]), (slice(n - half, n), x[n - window :])):
        poly = fit @ block  # (order+1, k)
        at = s[:half] if rows.start == 0 else s[-half:]
        d = np.zeros((len(at), order + 1))
        for p in powers[deriv:]:
            d[:, p] = np.prod(np.arange(p - deriv + 1, p + 1)) * at ** (p - deriv)
        out[rows] = d @ poly / dt**deriv
    return out


def savgol_t(x: np.ndarray, t: np.ndarray, window: int, deriv: int, order: int = 3) -> np.ndarray:
    """Savitzky–Golay on the actual sample times: a least-squares polynomial in real time per window.

    Like :func:`savgol` (the same window of ``window`` samples centred on each
    sample, the first and last full window's polynomial at the edges), but the
    polynomial is fitted against the samples' own times ``t`` rather than a
    uniform grid, so jittered or unevenly spaced stamps give the right
    derivatives. Equal to :func:`savgol` on a uniform grid (to rounding).
    """
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    n, half = len(x), window // 2
    start = np.clip(np.arange(n) - half, 0, n - window)  # first sample of each sample's window
    idx = start[:, None] + np.arange(window)  # (n, window)
    centre = t[start + half]
    h = float(np.median(np.diff(t)))  # time unit of the fit (conditioning)
    u = (t[idx] - centre[:, None]) / h  # (n, window)
    V = u[:, :, None] ** np.arange(order + 1)  # (n, window, order+1)
    VtV = np.einsum("nwi,nwj->nij", V, V)
    # d^deriv/du^deriv of the polynomial at the sample's own time
    at = (t - centre) / h
    e = np.zeros((n, order + 1))
    for p in range(deriv, order + 1):
        e[:, p] = np.prod(np.arange(p - deriv + 1, p + 1)) * at ** (p - deriv)
    coef = np.linalg.solve(VtV, e[:, :, None])[:, :, 0]  # (n, order+1): (VᵀV)⁻¹ e
    weights = np.einsum("nwi,ni->nw", V, coef) / h**deriv  # (n, window)
    return np.einsum("nw,nwk->nk", weights, x[idx])


def motion_from_poses(
    t: np.ndarray,
    quat_BE: np.ndarray,
    p_BoEo_B: np.ndarray | None = None,
    time_base: str = "seconds",
    window_s: float = 0.04,
) -> Motion:
    """The recorded motion with its derivatives, from the poses at each sample.

    Derivatives (only with a time base in seconds) come from a centred
    Savitzky–Golay filter (cubic, ``window_s`` wide at the median sample
    period, at least 5 samples; fitted against the actual sample times when
    the stamps are not evenly spaced, :func:`savgol_t`): of the sign-continuous
    quaternion q = q_BE, giving ``ω_E = 2 vec(q* ⊗ q̇)`` and
    ``α_E = 2 vec(q* ⊗ q̈)`` (the term q̇* ⊗ q̇ is a scalar), and of the positions,
    giving a_B. Offline, so centred: no lag, and a cubic over a window much
    shorter than a move follows the motion's acceleration to within its jerk's
    variation over the window.

    Args:
        t: (n,) increasing sample times, s (or rows). quat_BE: (n, 4) [w, x, y, z].
        p_BoEo_B: (n, 3) flange positions in B, m, or None.
        time_base: ``"seconds"`` or ``"index"`` (then no derivatives).
        window_s: the filter's window, s.
    """
    t = np.asarray(t, dtype=float)
    quat = _continuous(np.asarray(quat_BE, dtype=float))
    quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    R_EB = matrix_from_quat_wxyz(quat).transpose(0, 2, 1)
    t_ref = 0.5 * (t[0] + t[-1]) if len(t) else 0.0
    if time_base != "seconds" or len(t) < 5:
        return Motion(t, R_EB, quat, time_base=time_base, t_ref=t_ref)
    dt = float(np.median(np.diff(t)))
    window = max(5, int(round(window_s / dt)) | 1)
    if window > len(t):
        window = len(t) if len(t) % 2 else len(t) - 1
    steps = np.diff(t)
    if np.ptp(steps) <= 1e-6 * dt:  # evenly spaced: the uniform filter (a correlation, faster)
        sg = lambda x, d: savgol(x, window, d, dt)  # noqa: E731
    else:
        sg = lambda x, d: savgol_t(x, t, window, d)  # noqa: E731
    q_conj = quat_conjugate(sg(quat, 0))
    w_E = 2.0 * quat_multiply(q_conj, sg(quat, 1))[:, 1:]
    alpha_E = 2.0 * quat_multiply(q_conj, sg(quat, 2))[:, 1:]
    a_B = sg(np.asarray(p_BoEo_B, dtype=float), 2) if p_BoEo_B is not None else None
    return Motion(t, R_EB, quat, w_E, alpha_E, a_B, "seconds", 1.0 / dt, t_ref)


# --------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class ModelState:
    """The prediction as it is built, stage by stage; effects return a changed copy (``replace``).

    Attributes:
        motion: the motion the prediction follows (the timing stage may replace it).
        R_SE: (3, 3) the sensor's orientation on the flange (``v_S = R_SE v_E``).
        gravity_force_B: (3,) the tool's weight in B, N.
        bias_force_S: (3,) N. cog_S: (3,) centre of mass from the sensor origin, in S, m.
        bias_torque_S: (3,) N·m.
        force_S, torque_S: (n, 3) the wrench so far, N and N·m (None before the load stage).
    """

    motion: Motion
    R_SE: np.ndarray
    gravity_force_B: np.ndarray
    bias_force_S: np.ndarray
    cog_S: np.ndarray
    bias_torque_S: np.ndarray
    force_S: np.ndarray | None = None
    torque_S: np.ndarray | None = None

    @property
    def mass_kg(self) -> float:
        """The tool's mass from its weight, kg."""
        return float(np.linalg.norm(self.gravity_force_B)) / GRAVITY_M_S2

    @property
    def R_SB(self) -> np.ndarray:
        """(n, 3, 3) orientation of B in S at each sample."""
        return self.R_SE @ self.motion.R_EB

    def to_S(self, v_E: np.ndarray) -> np.ndarray:
        """(n, 3) vectors in E expressed in S."""
        return v_E @ self.R_SE.T

    @property
    def weight_S(self) -> np.ndarray:
        """(n, 3) the tool's weight in S at each sample, ``R_SE R_EB gravity_force_B``, N."""
        return self.to_S(self.motion.R_EB @ self.gravity_force_B)

    def replace(self, **changes: Any) -> ModelState:
        """A copy with some fields changed (effects never change arrays in place)."""
        return replace(self, **changes)


class Effect:
    """Base of an effect model: one physical term of the sensor model, with named parameters.

    Subclasses set ``stage`` (one of ``STAGES``), ``labels`` (one name per
    parameter, with its unit) and ``steps`` (a finite-difference step per
    parameter, in its unit: about 1e-3 of a typical value), and implement
    ``apply``. The factory registered through ``register_effects`` builds one;
    its keyword parameters are the effect's options.
    """

    stage: str = "load"
    labels: tuple[str, ...] = ()
    steps: tuple[float, ...] = ()
    description: str = ""
    online: bool = True
    """The ``kalman`` estimator models it: its name goes into the suggested options' ``effects`` (False: the
    report says it stays in the haptic rendering)."""

    def check(self, motion: Motion) -> str | None:
        """Why this effect cannot be tested on this recording (None: it can)."""
        return None

    def notes(self, motion: Motion) -> list[str]:
        """Caveats worth telling the user when testing it on this recording."""
        return []

    def initial(self) -> np.ndarray:
        """Parameters that switch the effect off (the prediction is unchanged)."""
        return np.zeros(len(self.labels))

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        """The state after this effect acted, with ``params`` (exact, not linearised)."""
        raise NotImplementedError

    def describe(self, params: np.ndarray) -> dict[str, Any]:
        """The parameters by physical name, JSON-ready (SI units)."""
        return {label: float(v) for label, v in zip(self.labels, params)}

    def summary(self, params: np.ndarray) -> str:
        """A short human-readable line of the parameters."""
        return ", ".join(f"{label} {v:.3g}" for label, v in zip(self.labels, params))

    def estimator_options(self, params: np.ndarray) -> dict[str, Any]:
        """Options of the ``kalman`` estimator that reproduce this effect online ({} when none)."""
        return {}


@runtime_checkable
class LocatesItself(Protocol):
    """An effect with a setting no linearisation can find: an instant, a time constant.

    At its switched-off parameters the prediction does not depend on such a
    setting (a step of zero size has no instant), so the workflow's linear
    candidate test would test it wherever it happened to start. Before each test
    the workflow calls ``locate`` with what the current model leaves; the effect
    sets the setting where that residual best fits its shape, and its
    ``initial()`` then carries it. Whatever stays a parameter is refined by the
    fit once the effect is named.
    """

    def locate(self, motion: Motion, residual: np.ndarray, weight_S: np.ndarray) -> None:
        """Set the effect's shape from ``residual`` (n, 6), what the current model leaves at the rows of
        ``motion`` in units of each axis's noise (force then torque), and the model's weight in S there,
        ``weight_S`` (n, 3) N."""
        ...


class Model:
    """The base model plus effects, with one parameter vector ``[base (12), effect 1, effect 2, ...]``.

    Args:
        effects: ``(name, effect)`` pairs, in the order they were added.
    """

    def __init__(self, effects: list[tuple[str, Effect]] | None = None):
        self.effects = list(effects or [])
        for name, effect in self.effects:
            if effect.stage not in STAGES:
                raise ValueError(f"effect {name}: stage {effect.stage!r} is not one of {', '.join(STAGES)}")
            if len(effect.steps) != len(effect.labels):
                raise ValueError(f"effect {name}: {len(effect.labels)} labels but {len(effect.steps)} steps")
        self.slices: dict[str, slice] = {}
        start = len(BASE_LABELS)
        for name, effect in self.effects:
            self.slices[name] = slice(start, start + len(effect.labels))
            start += len(effect.labels)
        self.size = start
        self.labels = list(BASE_LABELS) + [f"{n}.{label}" for n, e in self.effects for label in e.labels]
        self._timing_cache: tuple[Motion, bytes, Motion] | None = None

    def with_effect(self, name: str, effect: Effect) -> Model:
        """This model with one more effect (appended)."""
        return Model(self.effects + [(name, effect)])

    def initial(self, base: np.ndarray) -> np.ndarray:
        """A parameter vector: the given base parameters and every effect switched off."""
        return np.concatenate([base] + [e.initial() for _, e in self.effects])

    def effect_params(self, theta: np.ndarray, name: str) -> np.ndarray:
        """The parameters of one effect within ``theta``."""
        return theta[self.slices[name]]

    def _timed(self, motion: Motion, theta: np.ndarray) -> Motion:
        """The motion after the timing stage (cached: it is the costly one)."""
        timing = [(n, e) for n, e in self.effects if e.stage == "timing"]
        if not timing:
            return motion
        key = np.concatenate([theta[self.slices[n]] for n, _ in timing]).tobytes()
        cache = self._timing_cache
        if cache is not None and cache[0] is motion and cache[1] == key:
            return cache[2]
        state = ModelState(motion, np.eye(3), *np.split(theta[:12], 4))
        for name, effect in timing:
            state = effect.apply(state, theta[self.slices[name]])
        self._timing_cache = (motion, key, state.motion)
        return state.motion

    def weight_S(self, motion: Motion, theta: np.ndarray) -> np.ndarray:
        """(n, 3) the tool's weight in S (after the timing and mount stages), N."""
        state = ModelState(self._timed(motion, theta), np.eye(3), *np.split(np.asarray(theta[:12], float), 4))
        for name, effect in self.effects:
            if effect.stage == "mount":
                state = effect.apply(state, theta[self.slices[name]])
        return state.weight_S

    def predict(self, motion: Motion, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The predicted reading ``(force_S (n, 3) N, torque_S (n, 3) N·m)`` along ``motion``."""
        gravity_force_B, bias_force_S, cog_S, bias_torque_S = np.split(np.asarray(theta[:12], float), 4)
        state = ModelState(self._timed(motion, theta), np.eye(3), gravity_force_B, bias_force_S, cog_S, bias_torque_S)
        for stage in STAGES[1:]:
            if stage == "load":
                weight_S = state.weight_S
                state = state.replace(force_S=weight_S, torque_S=cross(state.cog_S, weight_S))
            if stage == "bias":
                state = state.replace(
                    force_S=state.force_S + state.bias_force_S, torque_S=state.torque_S + state.bias_torque_S
                )
            for name, effect in self.effects:
                if effect.stage == stage:
                    state = effect.apply(state, theta[self.slices[name]])
        return state.force_S, state.torque_S

    def predict6(self, motion: Motion, theta: np.ndarray) -> np.ndarray:
        """The predicted reading as (n, 6): force then torque."""
        force_S, torque_S = self.predict(motion, theta)
        return np.concatenate([force_S, torque_S], axis=1)

    def jacobian(self, motion: Motion, theta: np.ndarray, columns: slice | None = None) -> np.ndarray:
        """(n, 6, k) derivative of ``predict6`` by each parameter in ``columns`` (default: all).

        Forward differences for the base parameters (linear but for the mass
        in an inertial term), central differences with the effect's ``steps``
        for effect parameters.
        """
        columns = columns if columns is not None else slice(0, self.size)
        index = range(self.size)[columns]
        steps = np.concatenate([BASE_STEPS] + [np.asarray(e.steps, float) for _, e in self.effects])
        f0 = self.predict6(motion, theta) if any(i < 12 for i in index) else None
        out = np.empty((len(motion), 6, len(index)))
        for j, i in enumerate(index):
            h = steps[i]
            plus = theta.copy()
            plus[i] += h
            if i < 12:
                out[:, :, j] = (self.predict6(motion, plus) - f0) / h
            else:
                minus = theta.copy()
                minus[i] -= h
                out[:, :, j] = (self.predict6(motion, plus) - self.predict6(motion, minus)) / (2 * h)
        return out
