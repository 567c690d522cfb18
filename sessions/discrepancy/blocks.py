"""Passes over every row of a recording in blocks of rows: the prediction, the weight in S, the batch fit.

The fit itself runs on at most ``max_fit_samples`` rows; what runs on every
row (the contact gate, the robust start's residuals, the report's RMS, the
batch fit beside them) is done here ``BLOCK_ROWS`` rows at a time, so its
temporaries are a few megabytes whatever the length of the recording (a
whole-array prediction of a 600 000-row file made (n, 3, 3) temporaries of
43 MB each, many at once), and each block's arrays stay in the processor's
cache. Results do not depend on the blocks:

* a prediction is row by row once the timing stage has moved the motion; the
  timing effects (``time_lag``, ``clock_skew``) interpolate the recording
  between the samples either side of a shifted time, so each block's timing
  stage runs on the block and the rows within the effects' reach (and a few
  samples more) either side of it, whose interpolation is then that of the
  whole recording; an effect not known to be row by row (``hysteresis``
  carries a state from row to row; a plugin's timing or other effect) is
  predicted on the whole arrays, as before;
* the batch fit is solved by blockwise QR (TSQR: the R factor of each block's
  rows, stacked, factored again), the conditioning of ``lstsq`` on the
  stacked rows, with its residuals computed block by block; a recording of
  at most ``BLOCK_ROWS`` rows is one block: ``batch_fit`` itself.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from hapticlab.core.estimation.batch import batch_fit
from hapticlab.core.estimation.model import contact_wrench
from hapticlab.core.frames import skew_stack
from hapticlab.core.parallel import thread_map
from hapticlab.core.sensor_model import Model, Motion
from hapticlab.core.sensor_model.effect import ModelState
from hapticlab.plugins.effects.bias_drift import BiasDrift
from hapticlab.plugins.effects.gain_crosstalk import GainCrosstalk
from hapticlab.plugins.effects.inertia import Inertia
from hapticlab.plugins.effects.mount_rotation import MountRotation
from hapticlab.plugins.effects.payload_change import PayloadChange
from hapticlab.plugins.effects.time_lag import TimeLag
from hapticlab.plugins.effects.warm_up import WarmUp
from hapticlab.sessions.discrepancy.ramp import PayloadRamp
from hapticlab.sessions.discrepancy.skew import ClockSkew

BLOCK_ROWS = 16384
"""Rows per block: (n, 3) temporaries of 384 kB, in cache; larger blocks measured slower, not faster."""

ROW_BY_ROW = (BiasDrift, GainCrosstalk, Inertia, MountRotation, PayloadChange, WarmUp, PayloadRamp)
"""Effects (after the timing stage) whose prediction at a row depends on that row alone."""


def row_blocks(n: int, block: int = BLOCK_ROWS) -> Iterator[slice]:
    """Consecutive slices of at most ``block`` rows covering ``range(n)``."""
    for start in range(0, n, block):
        yield slice(start, min(start + block, n))


def _rows(motion: Motion, rows: slice) -> Motion:
    """The rows of ``motion`` (shifted or not) as a recorded motion of their own, with its ``t_ref``."""
    pick = lambda a: None if a is None else a[rows]  # noqa: E731 (a one-line closure)
    return Motion(
        motion.t[rows],
        motion.R_EB[rows],
        motion.quat_BE[rows],
        pick(motion.w_E),
        pick(motion.alpha_E),
        pick(motion.a_B),
        motion.time_base,
        motion.rate_hz,
        motion.t_ref,
    )


def _reach_s(model: Model, motion: Motion, theta: np.ndarray) -> float | None:
    """How far in time the timing stage looks from a row, s (0 without timing effects; None when a timing
    effect's reach is not known: a plugin's)."""
    reach = 0.0
    for name, effect in model.effects:
        if effect.stage != "timing":
            continue
        params = theta[model.slices[name]]
        if isinstance(effect, TimeLag):
            reach += abs(float(params[0]))
        elif isinstance(effect, ClockSkew):
            span = max(abs(float(motion.t[0]) - motion.t_ref), abs(float(motion.t[-1]) - motion.t_ref))
            reach += abs(float(params[0])) + abs(float(params[1])) * span
        else:
            return None
    return reach


def _block_plan(
    model: Model, motion: Motion, theta: np.ndarray, block: int
) -> tuple[Model, Callable[[slice], Motion]] | None:
    """The model of the stages after timing, and a function giving a block's motion after the timing stage;
    None when the model cannot be predicted block by block (:func:`predict_rows`)."""
    theta = np.asarray(theta, float)
    reach = _reach_s(model, motion, theta)
    if len(motion) <= block or reach is None:
        return None
    if not all(isinstance(e, ROW_BY_ROW) for _, e in model.effects if e.stage != "timing"):
        return None
    timing = [(n, e) for n, e in model.effects if e.stage == "timing"]
    rest = Model([(n, e) for n, e in model.effects if e.stage != "timing"])
    t, n = motion.t, len(motion)
    # rows either side of a block that the timing stage may interpolate between, with a margin of samples
    cushion = 2 + 2 * len(timing)

    def chunk(rows: slice) -> Motion:
        if not timing:
            return _rows(motion, rows)
        lo = max(0, int(np.searchsorted(t, t[rows.start] - reach, side="left")) - cushion)
        hi = min(n, int(np.searchsorted(t, t[rows.stop - 1] + reach, side="right")) + cushion)
        state = ModelState(_rows(motion, slice(lo, hi)), np.eye(3), *np.split(theta[:12], 4))
        for name, effect in timing:
            state = effect.apply(state, theta[model.slices[name]])
        return _rows(state.motion, slice(rows.start - lo, rows.stop - lo))

    return rest, chunk


def _rest_theta(model: Model, theta: np.ndarray) -> np.ndarray:
    """``theta`` without the timing effects' parameters."""
    keep = [theta[model.slices[n]] for n, e in model.effects if e.stage != "timing"]
    return np.concatenate([np.asarray(theta[:12], float), *keep])


def predict_rows(model: Model, motion: Motion, theta: np.ndarray, block: int | None = None) -> np.ndarray:
    """(n, 6) ``model.predict6(motion, theta)``, block by block (the same numbers; see the module docstring)."""
    return _by_blocks(model, motion, theta, block, "predict6", 6)


def weight_rows(model: Model, motion: Motion, theta: np.ndarray, block: int | None = None) -> np.ndarray:
    """(n, 3) ``model.weight_S(motion, theta)``, block by block."""
    return _by_blocks(model, motion, theta, block, "weight_S", 3)


def _by_blocks(
    model: Model, motion: Motion, theta: np.ndarray, block: int | None, method: str, width: int
) -> np.ndarray:
    """(n, ``width``) ``model.<method>(motion, theta)`` by blocks of ``block`` rows (None: ``BLOCK_ROWS``, read
    now), whole when the model cannot be, the blocks in threads (``hapticlab.core.parallel``: each writes its
    own rows)."""
    block = BLOCK_ROWS if block is None else block
    plan = _block_plan(model, motion, theta, block)
    if plan is None:
        result: np.ndarray = getattr(model, method)(motion, theta)
        return result
    rest, chunk = plan
    out, theta_rest = np.empty((len(motion), width)), _rest_theta(model, theta)

    def one(rows: slice) -> None:
        out[rows] = getattr(rest, method)(chunk(rows), theta_rest)

    thread_map(one, row_blocks(len(motion), block))
    return out


def _tsqr(blocks: Iterator[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Least-squares x of the stacked rows ``C x = y`` from (C_b, y_b) blocks: the R factor of each [C_b y_b],
    stacked and solved with ``lstsq`` (the stacked R has the same normal equations, so the same solution)."""
    factors = [np.linalg.qr(np.column_stack([C, y]), mode="r") for C, y in blocks]
    R = np.concatenate(factors)
    p = R.shape[1] - 1
    return np.linalg.lstsq(R[:, :p], R[:, p], rcond=None)[0]


def batch_fit_rows(
    force_S: np.ndarray, torque_S: np.ndarray, R_EB: np.ndarray, rows: np.ndarray, block: int | None = None
) -> dict[str, np.ndarray]:
    """``batch_fit(force_S[rows], torque_S[rows], R_EB[rows])`` (``rows`` a mask or an index), block by block
    above ``block`` rows (None: ``BLOCK_ROWS``; blockwise QR; below, ``batch_fit`` itself)."""
    block = BLOCK_ROWS if block is None else block
    index = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
    n = len(index)
    if n <= block:
        return batch_fit(force_S[index], torque_S[index], R_EB[index])
    slices = list(row_blocks(n, block))
    eye = np.eye(3)

    def force_blocks():
        for sl in slices:
            k = index[sl]
            m = len(k)
            C = np.concatenate([R_EB[k], np.broadcast_to(eye, (m, 3, 3))], axis=2).reshape(3 * m, 6)
            yield C, force_S[k].reshape(-1)

    def torque_blocks():
        for sl in slices:
            k = index[sl]
            m = len(k)
            C = np.concatenate([-skew_stack(force_S[k]), np.broadcast_to(eye, (m, 3, 3))], axis=2).reshape(3 * m, 6)
            yield C, torque_S[k].reshape(-1)

    x_f = _tsqr(force_blocks())
    x_t = _tsqr(torque_blocks())
    cog_S = x_t[:3]
    bias_torque_S = x_t[3:] + np.cross(cog_S, x_f[3:])
    x_torque = np.concatenate([cog_S, bias_torque_S])
    residual_force_S, residual_torque_S = np.empty((n, 3)), np.empty((n, 3))
    for sl in slices:
        k = index[sl]
        m = len(k)
        residual_force_S[sl], residual_torque_S[sl] = contact_wrench(
            force_S[k], torque_S[k], R_EB[k], np.tile(x_f, (m, 1)), np.tile(x_torque, (m, 1))
        )
    return {
        "gravity_force_B": x_f[:3],
        "bias_force_S": x_f[3:],
        "cog_S": cog_S,
        "bias_torque_S": bias_torque_S,
        "residual_force_S": residual_force_S,
        "residual_torque_S": residual_torque_S,
    }
