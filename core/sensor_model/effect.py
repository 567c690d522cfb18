"""The interface of an effect model: one physical term of the sensor model, acting at one stage.

The model (``model.py``) is the paper's base model plus any number of
**effects**, each a physical term with named parameters, registered by
plugins through ``register_effects`` (built-ins in ``hapticlab.plugins.effects``).
The measurement chain, in the order it is evaluated (``STAGES``)::

    timing   which pose belongs to which wrench sample     (time_lag)
    mount    R_SE, the sensor's orientation on the flange   (mount_rotation)
    ---      the tool's weight in S:  F = R_SE R_EB gravity_force_B,  τ = cog_S × F
    load     more true wrench on the sensor                 (inertia, payload_change)
    sensor   what the sensor makes of the true wrench       (gain_crosstalk, hysteresis)
    ---      + bias_force_S, + bias_torque_S
    bias     a bias that changes                            (bias_drift, warm_up)

An effect declares its ``stage`` and maps a :class:`ModelState` to a new one
(``apply``); effects of one stage run in the order they were added. With its
``initial()`` parameters an effect must leave the prediction unchanged (it is
"switched off"), so the workflow can test it from the current model.

Frames and units as everywhere (``hapticlab.core.frames``): ``R_EB`` maps B
into E, forces N, torques N·m, time s (or rows, see ``motion.py``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol, TypeVar, cast, runtime_checkable

import numpy as np

from hapticlab.core.frames import GRAVITY_M_S2
from hapticlab.core.sensor_model.motion import Motion

__all__ = ["STAGES", "Effect", "LocatesItself", "ModelState"]

_CACHE_LOCK = threading.Lock()
"""Guards the caches' inserts and evictions (a Jacobian's columns are predicted in threads)."""

CACHE_ENTRIES = 32
"""Terms kept per motion by :meth:`ModelState.cached` (the oldest is dropped first)."""

CACHE_ROWS = 32768
"""Longer motions keep nothing (:meth:`ModelState.cached`): a whole long recording is predicted once or twice,
block by block, and its terms would only hold memory; the fit's and the candidate test's rows are far fewer."""

T = TypeVar("T")

STAGES = ("timing", "mount", "load", "sensor", "bias")
"""Where an effect acts in the measurement chain, in evaluation order (see the module docstring)."""


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
        R_SB: np.ndarray = self.R_SE @ self.motion.R_EB
        return R_SB

    def to_S(self, v_E: np.ndarray) -> np.ndarray:
        """(n, 3) vectors in E expressed in S."""
        v_S: np.ndarray = v_E @ self.R_SE.T
        return v_S

    def cached(self, key: tuple[Any, ...], compute: Callable[[], T]) -> T:
        """``compute()``, or what it returned for the same ``key`` along this motion before.

        A finite-difference Jacobian moves one parameter at a time, so most
        terms of its predictions repeat exactly: an effect keys a term by the
        exact bytes of everything it depends on besides the motion (``key``
        starts with the term's name). The arrays are kept read-only: effects
        never change arrays in place. Safe from several threads (``hapticlab.core.parallel``).
        """
        cache = self.motion.cache
        if len(self.motion) > CACHE_ROWS:
            return compute()
        found = cache.get(key, cache)
        if found is not cache:
            return cast(T, found)
        value = compute()  # two threads may both compute one term: the same value, kept once
        for array in value if isinstance(value, tuple) else (value,):
            if isinstance(array, np.ndarray):
                array.flags.writeable = False
        with _CACHE_LOCK:
            if len(cache) >= CACHE_ENTRIES:
                cache.pop(next(iter(cache)), None)
            cache[key] = value
        return value

    def motion_S(self, name: str) -> np.ndarray:
        """(n, 3) the motion's ``w_E``, ``alpha_E`` or ``a_E`` (the flange's acceleration ``R_EB a_B``) in S.

        The caller checks that the motion has it.
        """

        def compute() -> np.ndarray:
            motion = self.motion
            if name == "a_E":
                return self.to_S(np.einsum("nij,nj->ni", motion.R_EB, cast(np.ndarray, motion.a_B)))
            return self.to_S(cast(np.ndarray, getattr(motion, name)))

        return self.cached(("motion_S", name, self.R_SE.tobytes()), compute)

    @property
    def weight_S(self) -> np.ndarray:
        """(n, 3) the tool's weight in S at each sample, ``R_SE R_EB gravity_force_B``, N."""
        key = ("weight_S", self.R_SE.tobytes(), np.asarray(self.gravity_force_B, float).tobytes())
        return self.cached(key, lambda: self.to_S(self.motion.R_EB @ self.gravity_force_B))

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
        """The state after this effect acted, with ``params`` (exact, not linearised).

        Called from several threads at once (a Jacobian's columns, a recording's row blocks:
        ``hapticlab.core.parallel``), so the result depends on ``state`` and ``params`` alone: keep
        anything computed in ``state.cached``, not on ``self``. (``payload_change`` notes the tool's mass
        for ``describe``; the weight's columns run first so it is the mass at the fitted parameters.)
        """
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
