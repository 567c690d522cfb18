"""Re-opening what the ``kalman`` estimator knows: a payload change, a torque bias that moved, a bias step.

Each widens the covariance of what changed (gravity along itself, the centre of gravity, a bias) back
towards its prior, so the next samples identify it again, and says so with an event.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from hapticlab.core.frames import skew_stack
from hapticlab.core.types import Event
from hapticlab.plugins.estimators.kalman import tilt_walk_kernel, torque_bias
from hapticlab.plugins.estimators.kalman.base import KalmanBase
from hapticlab.plugins.estimators.kalman.rules_kernel import torque_only_refusal
from hapticlab.plugins.estimators.kalman.stage import StageRun, innovations
from hapticlab.plugins.estimators.kalman.stage_kernel import GATED, UPDATED
from hapticlab.plugins.estimators.kalman.state_layout import ADAPT_REOPENS, ADAPT_TW

if TYPE_CHECKING:
    from hapticlab.plugins.estimators.kalman.mount_stage import MountStage


def bias_unknown(P: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """A copy of a stage's P with its bias (states 3..5) unknown again: its rows and columns zeroed, its
    variance the prior's (``prior`` (6,) the stage's prior stds; the compiled twin is ``rules_kernel.reopen_bias``)."""
    P = P.copy()
    P[3:6, :] = 0.0
    P[:, 3:6] = 0.0
    P[3:6, 3:6] = np.diag(prior[3:6] ** 2)
    return P


class Reopening(KalmanBase):
    """Payload change, torque-bias re-opening, bias re-identification (a part of :class:`KalmanEstimator`)."""

    def _watch_payload(
        self,
        t_ns: np.ndarray,
        y_f: np.ndarray,
        force_S: np.ndarray,
        torque_S: np.ndarray,
        R_EB: np.ndarray,
        A_f: np.ndarray,
        usable: np.ndarray,
        run_f: StageRun,
        x_before: np.ndarray,
    ) -> None:
        """Follow the force stage's refusal runs (``plugins.estimators.kalman.payload``); on a payload change re-open
        gravity and the centre of gravity, replay the run, say so (``payload_change``)."""
        gated = run_f.gated
        if not gated.any() and not self._payload.in_run:
            return
        e = innovations(y_f, A_f, x_before, run_f.X)
        change = self._payload.observe(
            t_ns, gated, usable, e, A_f, y_f, force_S, torque_S, R_EB, self.force.r, self.force.x[:3], self._positions
        )
        if change is None:
            return
        self._reopen_payload(change.window)
        dn = change.weight_change
        self.events.append(
            Event(
                change.t_ns,
                "payload_change",
                f"kalman: payload change of {dn:.3g} N ({dn / 9.81 * 1000:.0f} g) after "
                f"{change.run_s:.2f} s of refused samples; gravity and centre of gravity re-opened",
            )
        )

    def _reopen_payload(self, window: dict[str, np.ndarray]) -> None:
        """Re-open what a payload changes, then replay the refused window.

        A payload changes the weight along gravity only, so gravity's covariance is
        widened along its own direction in B (P_g += σ²·u uᵀ, u = g/|g|, σ the prior);
        its direction stays known and one orientation is enough to find the new
        weight. The centre of gravity moves in any direction: its covariance goes back
        to the prior (its component along gravity needs the tool to turn). The replay
        gives both stages the window's samples (no time step: they are already behind
        the stages' clock).
        """
        self.payload_changes += 1
        self._widen_weight()
        m = len(window["y"])
        zeros, ones = np.zeros(m), np.ones(m, dtype=bool)
        if self.mount_rotation:
            run_f = self.force.run(window["y"], window["R"], zeros, ones, self.gate2)
        else:
            run_f = self.force.run(window["y"], window["A"], zeros, ones, self.gate2, self.method)
        accepted = ~run_f.gated
        A_t = -skew_stack(window["f"])  # (about the measured force: torque_bias.py)
        self.torque.run(window["tq"], A_t, zeros, accepted, self.gate2, self.method)
        if self.mount_rotation:  # (the replay refined the mount too)
            self.R_SE = cast("MountStage", self.force).R_SE.copy()  # (mount_rotation: the force stage is one)
        self._seed_information()  # what the replay left known (gravity re-opened along itself)

    def _widen_weight(self) -> None:
        """Gravity's covariance widened along its own direction in B (P_g += σ²·u uᵀ, u = g/|g|, σ the prior),
        the centre of gravity's back to the prior (``_reopen_payload`` says why)."""
        tilt_walk_kernel.restart_windows.py_func(self._adapt[ADAPT_TW:])  # (a weight step is no turn's)
        P = self.force.P.copy()
        g = self.force.x[:3]
        u = g / max(float(np.linalg.norm(g)), 1e-9)
        P[:3, :3] += self.prior_f[0] ** 2 * np.outer(u, u)
        self.force.P = P
        biases = self._force_biases()  # (the centre of gravity re-opened, the physical bias kept: torque_bias.py)
        x, P = torque_bias.to_physical(self.torque.x, self.torque.P, *biases)
        P[:3, :] = 0.0
        P[:, :3] = 0.0
        P[:3, :3] = np.diag(self.prior_t[:3] ** 2)
        self.torque.x, self.torque.P = torque_bias.from_physical(x, P, *biases)

    def reidentify_weight(self, reason: str) -> None:
        """ReidentifiesWeight: the tool's weight unknown again along gravity and its centre of gravity back to
        the prior (as after a payload change, with no window to replay: the host asks after a sudden step it
        has held out), the bias kept."""
        self._widen_weight()
        self._seed_information()
        self.events.append(Event(self._last_t_ns or 0, "weight_reopened", f"weight re-opened: {reason}"))

    def _watch_torque_only(self, t_ns, gated_f, force_seen, run_t, dt, contact_force_S, contact_torque_S) -> None:
        """The reference's torque-only refusal rule (``rules_kernel.torque_only_refusal``, run as Python): over
        the block's samples in order, re-opening the torque bias where it says so, from the next sample on
        (in one-sample blocks, as the compiled cascade; at the block's end otherwise: the stage has already
        filtered the block)."""
        for k in range(len(t_ns)):
            failed = run_t.failed is not None and run_t.failed[k]
            what_t = GATED if run_t.gated[k] else (UPDATED if force_seen[k] and not failed else -1)
            if torque_only_refusal.py_func(
                self._adapt,
                bool(gated_f[k]),
                bool(force_seen[k]),
                what_t,
                float(dt[k]),
                contact_force_S[k],
                contact_torque_S[k],
            ):
                self._reopen_torque_bias(int(t_ns[k]))

    def _reopen_torque_bias(self, t_ns: int) -> None:
        """The torque bias unknown again (P's bias rows and columns zeroed, its diagonal the prior; Λ re-seeded
        from that P: ``rules_kernel.reopen_bias``), the centre of gravity as known."""
        P = self.torque.P = bias_unknown(self.torque.P, self.prior_t)
        self._information["torque"] = np.linalg.inv(P[:6, :6])
        self._torque_reopened(t_ns)

    def _torque_reopened(self, t_ns: int) -> None:
        self.events.append(
            Event(
                t_ns,
                "torque_bias_reopened",
                (
                    f"kalman: torque bias re-opened after {self.torque_reopen_s:g} s of samples the force stage "
                    f"accepted and the torque stage refused (a torque drift, not a contact; "
                    f"{int(self._adapt[ADAPT_REOPENS])} so far)"
                ),
                {"reopens": int(self._adapt[ADAPT_REOPENS])},
            )
        )

    def reidentify_bias(self, reason: str) -> None:
        """Reidentifies: the sensor's bias (force and torque) as unknown again, its covariance back to the prior.

        The host asks for it after a sensor bias step; the rest (the tool's weight, its centre of gravity,
        the mount) stays known, so the new bias is found from the next samples and the covariance-based
        convergence flags drop until it is.
        """
        for stage, prior in ((self.force, self.prior_f), (self.torque, self.prior_t)):
            stage.P = bias_unknown(stage.P, prior)
        self._seed_information()
        tilt_walk_kernel.restart_windows.py_func(self._adapt[ADAPT_TW:])  # (a bias step is no turn's)
        self.events.append(Event(self._last_t_ns or 0, "bias_reopened", f"bias re-opened: {reason}"))
