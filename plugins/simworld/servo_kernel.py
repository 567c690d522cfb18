"""The simulated servoed robot's state at given times, compiled: ``ServoedMotion.evaluate``.

In a teleoperated simulation the robot's motion is only known up to now, so the
simulated sensor and kinematics ask for it one sample at a time (a 1 kHz loop:
one call per reading); in numpy that is some twenty calls on (1, 3) arrays, each
paying numpy's per-call overhead, for every reading. Within step k
(τ = t − t_k ≥ 0, the step's state a row of the motion's history)::

    p(t) = p_k + v_k τ + ½ a_k τ²,   v(t) = v_k + a_k τ,   a(t) = a_k
    R_BE(t) = R_k (I + [φ]× + ½ [φ]×²),  φ = w_k τ + ½ α_k τ²,
    w_E(t) = w_k + α_k τ,   α_E(t) = α_k

``plugins/simworld/servo.py``'s ``evaluate_reference`` is the same in numpy, the
reference the tests compare with.

Compile cost: well under a second the first time, then loaded from ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

P, V, A, R, W, ALPHA = 0, 3, 6, 9, 18, 21
"""Column offsets of a history row: p (3) m, v (3) m/s, a (3) m/s², R_BE (9, row-major), w_E (3) rad/s,
α_E (3) rad/s²."""


@njit(cache=True)
def evaluate(history, t, dt, first, newest, R_BE, p, v, a, w, alpha):
    """Fill the state at times ``t`` (n,) s from the steps' ``history`` (size, 24) rows (step k in row
    k % size); each time uses its own step, clamped to [``first``, ``newest``] (the steps kept).

    Outputs, written in place: R_BE (n, 3, 3); p (n, 3) m; v (n, 3) m/s; a (n, 3) m/s²; w (n, 3) rad/s;
    alpha (n, 3) rad/s².
    """
    size = history.shape[0]
    M = np.empty((3, 3))
    for i in range(t.shape[0]):
        k = int(math.floor(t[i] / dt + 1e-9))
        k = min(max(k, first), newest)
        row = history[k % size]
        tau = max(t[i] - k * dt, 0.0)
        f0 = row[W] * tau + 0.5 * row[ALPHA] * tau * tau
        f1 = row[W + 1] * tau + 0.5 * row[ALPHA + 1] * tau * tau
        f2 = row[W + 2] * tau + 0.5 * row[ALPHA + 2] * tau * tau
        # M = [φ]× + ½ [φ]×²  ([φ]×² = φφᵀ − |φ|² I)
        M[0, 0] = 0.5 * (-f1 * f1 - f2 * f2)
        M[1, 1] = 0.5 * (-f0 * f0 - f2 * f2)
        M[2, 2] = 0.5 * (-f0 * f0 - f1 * f1)
        M[0, 1] = -f2 + 0.5 * (f0 * f1)
        M[1, 0] = f2 + 0.5 * (f0 * f1)
        M[0, 2] = f1 + 0.5 * (f0 * f2)
        M[2, 0] = -f1 + 0.5 * (f0 * f2)
        M[1, 2] = -f0 + 0.5 * (f1 * f2)
        M[2, 1] = f0 + 0.5 * (f1 * f2)
        for r in range(3):
            for c in range(3):
                s = row[R + 3 * r] * M[0, c] + row[R + 3 * r + 1] * M[1, c] + row[R + 3 * r + 2] * M[2, c]
                R_BE[i, r, c] = row[R + 3 * r + c] + s
        for j in range(3):
            p[i, j] = row[P + j] + row[V + j] * tau + 0.5 * row[A + j] * tau * tau
            v[i, j] = row[V + j] + row[A + j] * tau
            a[i, j] = row[A + j]
            w[i, j] = row[W + j] + row[ALPHA + j] * tau
            alpha[i, j] = row[ALPHA + j]


def warm_up() -> None:
    """Compile (or load from the cache) ``evaluate`` before the first live tick."""
    out = [np.empty((1, 3, 3))] + [np.empty((1, 3)) for _ in range(5)]
    evaluate(np.zeros((2, 24)), np.zeros(1), 1e-3, 0, 0, *out)
