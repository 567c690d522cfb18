"""A ``kalman`` estimator's state saved and restored: a warm start from the last session.

``state()`` is a JSON-serialisable snapshot (a session writes it beside its recording as
``<recording>.calibration.json``); ``load_state()`` starts from one, and refuses one that does not fit
this estimator's options with a ``warm_start: ...`` error.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from hapticlab.plugins.estimators.kalman import tilt_walk_kernel, torque_bias
from hapticlab.plugins.estimators.kalman.base import KalmanBase
from hapticlab.plugins.estimators.kalman.noise import NOISE_FLOOR, NOISE_WINDOW
from hapticlab.plugins.estimators.kalman.options import mount_matrix
from hapticlab.plugins.estimators.kalman.rules_kernel import set_gravity_direction
from hapticlab.plugins.estimators.kalman.state_layout import (
    ADAPT_COUNT_F,
    ADAPT_COUNT_T,
    ADAPT_FORCE_SEEN,
    ADAPT_GRAVITY_DIR,
    ADAPT_GRAVITY_KNOWN,
    ADAPT_TILT,
    ADAPT_TORQUE_SEEN,
    ADAPT_TW,
)

if TYPE_CHECKING:
    from hapticlab.plugins.estimators.kalman.mount_stage import MountStage


TORQUE_BIAS = "about the measured force"
"""How a state saved since the torque stage's bias is about the measured force says so (``torque_bias``); one
without it holds the physical bias, converted on loading."""


class WarmStart(KalmanBase):
    """Saving and restoring the estimator's state (a part of :class:`KalmanEstimator`)."""

    def state(self) -> dict:
        """A JSON-serialisable snapshot: estimator name, x and P of both stages, flags, last t_ns, the noise
        estimates and the identified rule's information (a warm start picks up what the motion had identified:
        seeded from P alone it would start from what the bias's random walk had not yet forgotten)."""
        return {
            "estimator": "kalman",
            "bias_rate": self.bias_rate,
            "force": {"x": self.force.x.tolist(), "P": (0.5 * (self.force.P + self.force.P.T)).tolist()},
            "torque": {"x": self.torque.x.tolist(), "P": (0.5 * (self.torque.P + self.torque.P.T)).tolist()},
            "torque_bias": TORQUE_BIAS,  # its bias about the measured force (torque_bias.py; params: the physical)
            "converged_force": self.converged_force,
            "converged_torque": self.converged_torque,
            # the stages settled (at the pose: identified as well, which the flags above need not say)
            "settled_force": bool(self._adapt[ADAPT_FORCE_SEEN]),
            "settled_torque": bool(self._adapt[ADAPT_TORQUE_SEEN]),
            "t_ns": self._last_t_ns,
            "mount_rotation": self.mount_rotation,
            "mount_R_SE": self.R_SE.tolist(),
            "noise_force_S": np.sqrt(self.force.r).tolist(),
            "noise_torque_S": np.sqrt(self.torque.r).tolist(),
            # the tilt walk's bookkeeping (its learnt state's windows go on in a warm start: tilt_walk.restore)
            "tilt": self._tilt_state(),
            "params": self.params(),
            # the identified rule's information per stage (plugins.estimators.kalman.identified): what the motion
            # has told
            "information": {k: v.tolist() for k, v in self._information.items()},
        }

    def load_state(self, source: str | Path | dict) -> None:
        """Start from a ``state()`` (a dict or a JSON file); ValueError("warm_start: ...") if unusable."""
        where = "the given state"
        if not isinstance(source, dict):
            where = str(source)
            source = read_state_file(Path(source))
        if not isinstance(source, dict) or source.get("estimator") != "kalman":
            name = source.get("estimator") if isinstance(source, dict) else None
            raise ValueError(f"warm_start: {where} is not a kalman state (estimator {name!r})")
        for key, mine in (("bias_rate", self.bias_rate), ("mount_rotation", self.mount_rotation)):
            if bool(source.get(key)) != mine:
                raise ValueError(f"warm_start: {where} has {key}={source.get(key)!r}, this estimator {mine}")
        R_SE = None
        if self.mount_rotation:
            try:
                R_SE = mount_matrix(None, source.get("mount_R_SE"))
            except ValueError as exc:
                raise ValueError(f"warm_start: {where}: {exc}") from None
        loaded = []
        for key, stage in (("force", self.force), ("torque", self.torque)):
            try:
                x = np.array(source[key]["x"], dtype=float)
                P = np.array(source[key]["P"], dtype=float)
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"warm_start: {where}: {key} stage has no usable x and P ({exc})") from None
            n = stage.n
            if x.shape != (n,) or P.shape != (n, n) or not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
                raise ValueError(f"warm_start: {where}: {key} stage needs finite x ({n},) and P ({n}, {n})")
            scale = float(np.abs(P).max()) if P.size else 0.0
            if not np.allclose(P, P.T, rtol=1e-9, atol=1e-12 * scale) or np.linalg.eigvalsh((P + P.T) / 2).min() <= 0:
                raise ValueError(f"warm_start: {where}: {key} stage's P is not symmetric positive definite")
            loaded.append((stage, x, (P + P.T) / 2))
        information = {}
        for key, info in (source.get("information") or {}).items():  # (states saved before it: none)
            info = np.array(info, dtype=float) if key in ("force", "torque") else None
            if (
                info is None
                or info.shape != (6, 6)
                or not np.all(np.isfinite(info))
                or not np.allclose(info, info.T)
                or np.linalg.eigvalsh(info).min() <= 0
            ):
                raise ValueError(
                    f"warm_start: {where}: information[{key!r}] is not a symmetric positive definite 6x6 matrix"
                )
            information[key] = info
        for stage, x, P in loaded:
            stage.x, stage.P = x, P
        if loaded and source.get("torque_bias") != TORQUE_BIAS:  # (saved before: the physical bias)
            torque = self.torque
            torque.x, torque.P = torque_bias.from_physical(torque.x, torque.P, *self._force_biases())
            if "torque" in information:
                information["torque"] = torque_bias.information_from_physical(information["torque"], self.force.x[3:6])
        if loaded:
            self._seed_information()
            self._information.update(information)  # what the motion had identified, not only what P still holds
        if R_SE is not None:
            cast("MountStage", self.force).R_SE = self.R_SE = R_SE  # (mount_rotation: the force stage is one)
        # (a state saved before "settled_*" was kept: its flags were the identified or covariance rule's)
        self._cog_known = bool(source.get("settled_torque", source.get("converged_torque")))
        self._mass_known = bool(source.get("settled_force", source.get("converged_force")))
        if self.noise_auto:  # the noise estimate carries over, as if its window were full
            for key, stage, floor, auto in (
                ("noise_force_S", self.force, NOISE_FLOOR[0], self.noise_auto_force),
                ("noise_torque_S", self.torque, NOISE_FLOOR[1], self.noise_auto_torque),
            ):
                if not auto:
                    continue
                noise = np.array(source.get(key, np.sqrt(stage.r)), dtype=float)
                if noise.shape == (3,) and np.all(np.isfinite(noise)):
                    stage.r = np.maximum(noise, floor) ** 2
            self.torque.rc = self.force.r.copy()
            self._adapt[[ADAPT_COUNT_F, ADAPT_COUNT_T]] = NOISE_WINDOW
        tilt = source.get("tilt")  # (none: a state saved before it, or without the walk)
        tilt = {} if tilt is None else tilt
        if not isinstance(tilt, dict):
            raise ValueError(
                f"warm_start: {where}: tilt: must be a table (last_A, gravity_direction_B, walk), "
                f"got {type(tilt).__name__}"
            )
        self._load_tilt(tilt, where)

    def _tilt_state(self) -> dict | None:
        """``state()["tilt"]`` with the tilt walk on (None without): the last pose's A (None before one), the
        direction tilts are measured about (None before the weight is identified), the learnt walk's state."""
        if not (self.tilt_walk_auto or self.force.q_tilt.any() or self.torque.q_tilt.any()):
            return None
        adapt = self._adapt
        return {
            "last_A": None if np.isnan(adapt[ADAPT_TILT]) else adapt[ADAPT_TILT : ADAPT_TILT + 9].tolist(),
            "gravity_direction_B": adapt[ADAPT_GRAVITY_DIR : ADAPT_GRAVITY_DIR + 3].tolist()
            if adapt[ADAPT_GRAVITY_KNOWN]
            else None,
            "walk": adapt[ADAPT_TW:].tolist() if self.tilt_walk_auto else None,
        }

    def _load_tilt(self, tilt: dict, where: str) -> None:
        """A warm start's tilt bookkeeping (``state()["tilt"]``; a state saved before it: the direction from the
        weight if it had been identified, the walk learnt anew): the last pose, the direction of gravity tilts are
        measured about, the learnt walk."""
        try:
            if tilt.get("last_A") is not None:
                last_A = np.array(tilt["last_A"], dtype=float)
                if last_A.shape != (9,) or not np.all(np.isfinite(last_A)):
                    raise ValueError("last_A must be 9 finite numbers")
                self._adapt[ADAPT_TILT : ADAPT_TILT + 9] = last_A
            if tilt.get("gravity_direction_B") is not None:
                direction = np.array(tilt["gravity_direction_B"], dtype=float)
                if direction.shape != (3,) or not abs(np.linalg.norm(direction) - 1.0) < 1e-6:
                    raise ValueError("gravity_direction_B must be a unit vector (3 numbers)")
                set_gravity_direction.py_func(self._adapt, direction)
            elif self._mass_known:  # the tilt measured about the weight it had identified
                set_gravity_direction.py_func(self._adapt, self.force.x[:3])
            if self.tilt_walk_auto and tilt.get("walk") is not None:
                self._set_tilt_walk(tilt_walk_kernel.restore(self._adapt[ADAPT_TW:], tilt["walk"]))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"warm_start: {where}: tilt: {exc}") from None


MAX_STATE_BYTES = 16 << 20
"""A saved state is read up to 16 MiB (a kalman state with its information matrices is ~10 kB)."""


def read_state_file(path: Path) -> Any:
    """A ``<recording>.calibration.json``: a regular file of at most ``MAX_STATE_BYTES``, JSON; ValueError
    ("warm_start: ...") otherwise (a device or a FIFO is refused before it is opened)."""
    if path.exists() and not path.is_file():
        raise ValueError(f"warm_start: {path} is not a regular file (a folder, a device or a FIFO)")
    try:
        with path.open("rb") as f:
            data = f.read(MAX_STATE_BYTES + 1)
        if len(data) > MAX_STATE_BYTES:
            raise ValueError(f"warm_start: {path} is larger than {MAX_STATE_BYTES >> 20} MiB: not a saved state")
        return json.loads(data.decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"warm_start: cannot read {path}: {exc}") from None
