"""What the simulated sensor's six channels make of the wrench on them: calibration error, loading
hysteresis, bias (offset, drift, warm-up, random walk), white noise and saturation.

The world (``physics.py``) computes the true wrench on the sensor; a
:class:`SensorChannels` turns it into the reading, force (N) then torque (N·m)
side by side, (N, 6)::

    load    = (I + G) · true wrench                      (calibrated)
    reading = clip(play_r(load) + bias(t) + noise, ±saturation)   (read)

with ``G`` the calibration error (``SensorParams.gain_*``), ``play_r`` the
channels' play operators of half-widths r (``SensorParams.hysteresis_*``), and
``bias(t) = bias + drift·t + warm-up·exp(−t/τ) + drift_rw·W(t)`` (W a standard
Brownian path). Noise and random walk come from ``randomness.py``, so every
part is a pure function of (seed, time).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hapticlab.core.sensor_model.play_kernel import play
from hapticlab.plugins.simworld.params import SensorParams
from hapticlab.plugins.simworld.randomness import DRIFT_STREAM, NOISE_STREAM, GrowingPath, RandomWalk, gaussian_noise
from hapticlab.plugins.simworld.rows import apply_rows as _apply

__all__ = ["PlayHysteresis", "SensorChannels"]


class PlayHysteresis(GrowingPath):
    """The sensor channels' hysteresis: their load through play operators (``core/sensor_model/play_kernel.py``).

    The operator's state is followed along the loading path on a grid of
    ``grid_s`` from t = 0 (where it starts relaxed, at the load), grown block by
    block as later times are asked for and cached, so the reading at a time
    never depends on the times asked for before: at time t it is the state at
    the grid point before t moved on to the load at t. Before t = 0 the state
    is the load at 0.

    Args:
        r: (6,) half-widths, force (N) then torque (N·m), ≥ 0.
        load: the channels' load at times (N,) s, as (N, 6).
        ahead: grow the path a ``block`` at a time (a scripted world); False: only up to the time asked
            for (a world that follows targets sent as it runs is not known ahead of now).
    """

    def __init__(self, r: np.ndarray, load, grid_s: float = 1e-3, block: int = 1000, ahead: bool = True):
        super().__init__(np.empty((0, 6)))  # the operator's output at grid points 0, 1, ...
        self.r = np.asarray(r, dtype=float)
        self.load, self.grid_s, self.block, self.ahead = load, grid_s, block, ahead

    def _more(self, points: int) -> np.ndarray:
        start = len(self._path)
        end = start + self.block if self.ahead else points
        x = self.load(np.arange(start, end) * self.grid_s)
        out = np.empty_like(x)
        play(x, self.r, x[0].copy() if start == 0 else self._path[-1], out)
        return out

    def __call__(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(N, 6) what the channels read at times ``t`` (N,) s for the load ``x`` (N, 6) there."""
        k = np.floor(np.maximum(t, 0.0) / self.grid_s).astype(np.int64)
        self._ensure(int(k.max(initial=0)) + 1)
        h = self._path.take(k, axis=0)
        return np.minimum(np.maximum(h, x - self.r), x + self.r)


class SensorChannels:
    """The simulated sensor's channels: what they read for the wrench on them, at times t.

    Args:
        sensor: the sensor's parameters (noise, bias, drift, warm-up, random walk, hysteresis,
            calibration error, saturation).
        seed: the world's seed (the noise and random-walk streams, ``randomness.py``).
        load: ``load(t)`` → (N, 6) the calibrated load at times (N,) s: what the hysteresis follows
            along the loading path.
        ahead: the hysteresis may follow the load ahead of the time asked for (False: a world that
            follows targets sent as it runs is only known up to now).
    """

    def __init__(self, sensor: SensorParams, seed: int, load: Callable[[np.ndarray], np.ndarray], ahead: bool = True):
        self.sensor = sensor
        # force then torque, (6,) each: N and N·m, N/s and N·m/s, N/√s and N·m/√s
        self._bias_S = np.concatenate([sensor.bias_force_S, sensor.bias_torque_S])
        self._drift_S = np.concatenate([sensor.drift_force_S, sensor.drift_torque_S])
        self._drift_rw_S = np.concatenate([sensor.drift_force_rw_S, sensor.drift_torque_rw_S])
        self._warmup_S = np.concatenate([sensor.warmup_force_S, sensor.warmup_torque_S])
        """(6,) the bias's distance from its settled value at t = 0 (N, N·m), decaying with ``warmup_tau_s``"""
        self._noise_S = np.concatenate([sensor.noise_force_S, sensor.noise_torque_S])
        self._saturation_S = np.concatenate([sensor.saturation_force_S, sensor.saturation_torque_S])
        has_gain = np.any(sensor.gain_force_S != 0) or np.any(sensor.gain_torque_S != 0)
        self._gain_S = (np.eye(3) + sensor.gain_force_S, np.eye(3) + sensor.gain_torque_S) if has_gain else None
        """``(I + G_f, I + G_t)``, each (3, 3), or None without a calibration error."""
        self.noise_key = int(np.random.SeedSequence(seed, spawn_key=(NOISE_STREAM,)).generate_state(1, np.uint64)[0])
        """The white-noise stream's key (``randomness.gaussian_noise``)."""
        has_walk = np.any(sensor.drift_force_rw_S > 0) or np.any(sensor.drift_torque_rw_S > 0)
        self._walk = RandomWalk(seed, DRIFT_STREAM, channels=6) if has_walk else None
        widths = np.concatenate([sensor.hysteresis_force_S, sensor.hysteresis_torque_S])
        self._hysteresis = PlayHysteresis(widths, load, ahead=ahead) if widths.any() else None

    def calibrated(self, wrench_S: np.ndarray) -> np.ndarray:
        """The load the channels see for the true wrench ``wrench_S`` (N, 6): ``(I + G)·`` it (in place)."""
        if self._gain_S is not None:  # calibration error: the sensor reads (I + G)·true
            wrench_S[:, :3] = _apply(self._gain_S[0], wrench_S[:, :3])
            wrench_S[:, 3:] = _apply(self._gain_S[1], wrench_S[:, 3:])
        return wrench_S

    def bias(self, t: np.ndarray) -> np.ndarray:
        """(N, 6) true bias at times ``t`` (N,) s: force (N) then torque (N·m)."""
        bias_S = self._bias_S + t[:, None] * self._drift_S
        if self._warmup_S.any():  # the electronics settling: exp(−t/τ) of the way still to go
            bias_S = bias_S + np.exp(-np.maximum(t, 0.0) / self.sensor.warmup_tau_s)[:, None] * self._warmup_S
        if self._walk is not None:
            bias_S = bias_S + self._walk(t) * self._drift_rw_S
        return bias_S

    def noise(self, t: np.ndarray) -> np.ndarray:
        """(N, 6) the white noise at times ``t`` (N,) s: force (N) then torque (N·m)."""
        return gaussian_noise(self.noise_key, np.rint(t * 1e9).astype(np.int64), 6) * self._noise_S

    def read(
        self, t: np.ndarray, load_S: np.ndarray, noise: bool = True, known: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the channels read at times ``t`` (N,) s for the calibrated load ``load_S`` (N, 6) there.

        ``known``: ``(bias(t), noise(t))`` already computed (they depend on the time alone: a device
        whose world is only known up to now still computes them ahead, in chunks), else computed here.

        Returns
        -------
        reading_S : (N, 6) force (N) then torque (N·m), clipped at saturation.
        bias_S : (N, 6) the true bias at ``t``.
        saturated : (N,) bool, True where any axis went beyond its range.
        """
        reading_S = load_S
        if self._hysteresis is not None:  # the channels follow their load through play operators
            reading_S = self._hysteresis(t, reading_S)
        bias_S = self.bias(t) if known is None else known[0]
        reading_S += bias_S
        if noise:
            reading_S += self.noise(t) if known is None else known[1]
        limit = self._saturation_S
        saturated = (np.abs(reading_S) > limit).any(axis=1)
        reading_S = np.minimum(np.maximum(reading_S, -limit), limit)  # np.clip, without its overhead
        return reading_S, bias_S, saturated
