"""The sensor model: the paper's base model plus effects, as one parameter vector along a recorded motion.

The discrepancy workflow (``hapticlab.sessions.discrepancy.workflow``) predicts what the
wrist sensor should read at every recorded sample from the robot's motion and
a model, and compares it with what it did read. :class:`Model` stacks the
paper's twelve base parameters and the parameters of its effects (each a
physical term, ``effect.py``) into one vector, predicts the reading by running
the measurement chain stage by stage (``STAGES``), and gives its Jacobian by
finite differences of the effects' ``apply`` (forward for the base
parameters, central for effect parameters, with each effect's ``steps``).

Frames and units as everywhere (``hapticlab.core.frames``): ``R_EB`` maps B
into E, forces N, torques N·m, time s (or rows, see ``motion.py``).
"""

from __future__ import annotations

import threading

import numpy as np

from hapticlab.core.frames import cross
from hapticlab.core.parallel import thread_map
from hapticlab.core.sensor_model.effect import CACHE_ROWS, STAGES, Effect, ModelState
from hapticlab.core.sensor_model.motion import Motion

__all__ = ["BASE_LABELS", "BASE_STEPS", "Model"]

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


def _loaded(state: ModelState) -> ModelState:
    """The state with the tool's weight and its moment as the wrench (kept along the motion: most predictions of a
    Jacobian share them)."""
    weight_S = state.weight_S
    c, g = np.asarray(state.cog_S, float), np.asarray(state.gravity_force_B, float)
    key = ("cog_S x weight_S", state.R_SE.tobytes(), g.tobytes(), c.tobytes())
    torque_S: np.ndarray = state.cached(key, lambda: cross(state.cog_S, weight_S))
    return state.replace(force_S=weight_S, torque_S=torque_S)


PREDICTIONS_KEPT = 4
"""Predictions a model keeps (:meth:`Model.predict6`) along motions of at most ``CACHE_ROWS`` rows."""


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
        self._predictions: list[tuple[Motion, bytes, np.ndarray]] = []
        self._lock = threading.Lock()

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
                state = _loaded(state)
            if stage == "bias":
                state = state.replace(
                    force_S=state.force_S + state.bias_force_S, torque_S=state.torque_S + state.bias_torque_S
                )
            for name, effect in self.effects:
                if effect.stage == stage:
                    state = effect.apply(state, theta[self.slices[name]])
        assert state.force_S is not None and state.torque_S is not None  # set by the load stage
        return state.force_S, state.torque_S

    def predict6(self, motion: Motion, theta: np.ndarray) -> np.ndarray:
        """The predicted reading as (n, 6): force then torque (read-only).

        The last ``PREDICTIONS_KEPT`` along motions of at most ``CACHE_ROWS`` rows are kept: a fit's step
        control and the next Jacobian ask for the same one.
        """
        key = np.asarray(theta, float).tobytes()
        kept = self._predictions
        with self._lock:
            for i, (source, k, prediction) in enumerate(kept):
                if source is motion and k == key:
                    kept.append(kept.pop(i))  # the most recently used last
                    return prediction
        force_S, torque_S = self.predict(motion, theta)
        prediction = np.concatenate([force_S, torque_S], axis=1)
        prediction.flags.writeable = False
        if len(motion) <= CACHE_ROWS:
            with self._lock:
                kept.append((motion, key, prediction))
                del kept[: max(0, len(kept) - PREDICTIONS_KEPT)]
        return prediction

    def jacobian(self, motion: Motion, theta: np.ndarray, columns: slice | None = None) -> np.ndarray:
        """(n, 6, k) derivative of ``predict6`` by each parameter in ``columns`` (default: all).

        Forward differences for the base parameters (linear but for the mass
        in an inertial term), central differences with the effect's ``steps``
        for effect parameters. The columns are independent predictions,
        computed in threads (``hapticlab.core.parallel``; the same numbers),
        the weight's three first: an effect may note the tool's mass from the
        last prediction it made (``payload_change``, for ``describe``), which
        is then the mass at ``theta``, as when the columns ran in order.
        """
        columns = columns if columns is not None else slice(0, self.size)
        index = range(self.size)[columns]
        steps = np.concatenate([BASE_STEPS] + [np.asarray(e.steps, float) for _, e in self.effects])
        f0 = self.predict6(motion, theta) if any(i < 12 for i in index) else None
        self._timed(motion, theta)  # the columns that keep the timing share it
        out = np.empty((len(motion), 6, len(index)))

        def column(job: tuple[int, int]) -> None:
            j, i = job
            h = steps[i]
            plus = theta.copy()
            plus[i] += h
            if i < 12:
                out[:, :, j] = (self.predict6(motion, plus) - f0) / h
            else:
                minus = theta.copy()
                minus[i] -= h
                out[:, :, j] = (self.predict6(motion, plus) - self.predict6(motion, minus)) / (2 * h)

        jobs = list(enumerate(index))
        thread_map(column, [job for job in jobs if job[1] < 3])  # the weight's columns
        thread_map(column, [job for job in jobs if job[1] >= 3])
        return out
