"""The paper's non-contact model (eqs. 18–19) and its contact wrench (eqs. 20–21).

    S_f   = R_EB · B_f + f0
    S_tau = p × (R_EB · B_f) + tau0

Every estimator of this model reports its state through these two functions,
so the contact wrench means the same thing whichever one produced it.

And which samples the model may see at all: ``SampleGuard`` refuses, per
sample, a NaN or inf, an R_EB that is not a rotation and a wrench beyond a
physical bound before an estimator's state can be touched by it, counts the
refusals and reports them as ``sample_refused`` events (docs/estimators.md,
"Refused samples").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from hapticlab.core.estimation import model_kernel as plausible_kernel
from hapticlab.core.frames import cross
from hapticlab.core.host.options import number
from hapticlab.core.types import AlignedSamples, Estimates, Event


def contact_wrench(
    force_S: np.ndarray, torque_S: np.ndarray, R_EB: np.ndarray, x_force: np.ndarray, x_torque: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Contact force and torque in S per sample (eqs. 20–21).

    Args:
        force_S: (m, 3) raw force, N. torque_S: (m, 3) raw torque, N·m.
        R_EB: (m, 3, 3) orientation of B in E.
        x_force: (m, 6) [gravity_force_B, bias_force_S] per sample, N.
        x_torque: (m, 6) [cog_S (m), bias_torque_S (N·m)] per sample.

    Returns:
        (contact_force_S (m, 3) N, contact_torque_S (m, 3) N·m).
    """
    gravity_S = (R_EB @ x_force[:, :3, None])[:, :, 0]
    contact_force_S = force_S - gravity_S - x_force[:, 3:]
    contact_torque_S = torque_S - cross(x_torque[:, :3], gravity_S) - x_torque[:, 3:]
    return contact_force_S, contact_torque_S


def named_params(x_force: np.ndarray, x_torque: np.ndarray) -> dict[str, list[float]]:
    """The model's parameters by physical name (SI units) from the two stage states."""
    return {
        "gravity_force_B": x_force[:3].tolist(),
        "bias_force_S": x_force[3:].tolist(),
        "cog_S": x_torque[:3].tolist(),
        "bias_torque_S": x_torque[3:].tolist(),
    }


# ------------------------------------------------------------------ which samples the model may see

MAX_FORCE = 1e4
"""Default ``max_force``, N: a force component beyond it is not a reading (a six-axis sensor's range is
~1e2–1e3 N; the live loop also checks the sensor's own range)."""
MAX_TORQUE = 1e3
"""Default ``max_torque``, N·m."""
LARGEST_BOUND = (1e6, 1e5)
"""The largest ``max_force`` (N) and ``max_torque`` (N·m) accepted: beyond, squares summed over a
long session come near the float range, and no sensor reads that much."""
ROTATION_TOLERANCE = 1e-6
"""An R_EB with ‖R_EB R_EBᵀ − I‖_F above this, or det ≤ 0, is not a rotation."""
REFUSAL_REPORT_NS = 1_000_000_000
"""After the first ``sample_refused`` event, at most one per this long (sample time), ns."""

NON_FINITE, NOT_A_ROTATION, BEYOND_THE_BOUND = "non-finite", "not a rotation", "beyond the bound"
REASONS = (NON_FINITE, NOT_A_ROTATION, BEYOND_THE_BOUND)
"""Why a sample is refused, in the order they are tested (code i + 1 in ``refusal_codes``)."""

_I3 = np.eye(3)


def wrench_bound(key: str, value: Any, largest: float) -> float:
    """A ``max_force`` / ``max_torque`` option: a finite number in (0, largest]; OptionError naming the key."""
    return number(key, value, above=0, maximum=largest, hint=" (a bound far above the sensor's range)")


def refusal_codes(
    force_S: np.ndarray,
    torque_S: np.ndarray,
    R_EB: np.ndarray,
    max_force: float,
    max_torque: float,
    extras: tuple[np.ndarray, ...] = (),
) -> np.ndarray:
    """(m,) int: 0 for a sample the model may see, else 1 + the index of its reason in ``REASONS``.

    Non-finite: a NaN or inf in force_S (m, 3), torque_S (m, 3), R_EB (m, 3, 3) or one of ``extras``
    (arrays of m rows the estimator also uses, e.g. positions). Not a rotation: ‖R Rᵀ − I‖_F >
    ROTATION_TOLERANCE or det R ≤ 0. Beyond the bound: a force component's magnitude above
    ``max_force`` (N) or a torque component's above ``max_torque`` (N·m).
    """
    m = len(force_S)
    finite = np.isfinite(force_S).all(1) & np.isfinite(torque_S).all(1) & np.isfinite(R_EB).all(axis=(1, 2))
    for extra in extras:
        finite &= np.isfinite(extra).reshape(m, -1).all(1)
    R = np.where(finite[:, None, None], R_EB, _I3)  # what is left to test is finite
    with np.errstate(over="ignore", invalid="ignore"):  # 1e300 entries overflow to inf: not a rotation
        G = R @ R.transpose(0, 2, 1)
        G -= _I3
        rotation = (np.einsum("kij,kij->k", G, G) <= ROTATION_TOLERANCE**2) & (np.linalg.det(R) > 0)
    inside = (np.abs(force_S).max(1) <= max_force) & (np.abs(torque_S).max(1) <= max_torque)
    return np.where(~finite, 1, np.where(~rotation, 2, np.where(~inside, 3, 0)))


def all_plausible(
    force_S: np.ndarray, torque_S: np.ndarray, R_EB: np.ndarray, max_force: float, max_torque: float
) -> bool:
    """True when ``refusal_codes`` would refuse none of the samples (a screen: False means "look closer").

    One compiled pass over the block (``core.estimation.model_kernel``; ``refusal_codes`` is the reference),
    cheaper than the numpy calls it replaces (``docs/estimators.md``, "Refused samples").
    """
    return plausible_kernel.all_plausible(force_S, torque_S, R_EB, max_force, max_torque, ROTATION_TOLERANCE)


class SampleGuard:
    """Refuses, per sample, what an estimator's model must not see; counts and reports the refusals.

    ``run(block, update, flags)`` gives ``update`` the block without its refused samples (the
    block itself when none is refused: the accepted samples' arithmetic is untouched), so the
    estimator's state is exactly what it would be had those samples never arrived. Refused rows
    of the result have NaN contact wrench, no contact, and the convergence flags of the row
    before them. Events: one ``sample_refused`` at the first refusal, then at most one per
    REFUSAL_REPORT_NS of sample time with the count since the last one.

    Args:
        source: the estimator's name, first word of the events' messages.
        max_force: bound on each force component's magnitude, N (``wrench_bound``).
        max_torque: bound on each torque component's magnitude, N·m.

    Attributes:
        refused: samples refused so far. by_reason: the same per reason (``REASONS``).
        events: the events not yet drained.
    """

    def __init__(self, source: str, max_force: float = MAX_FORCE, max_torque: float = MAX_TORQUE):
        self.source = source
        self.max_force = wrench_bound("max_force", max_force, LARGEST_BOUND[0])
        self.max_torque = wrench_bound("max_torque", max_torque, LARGEST_BOUND[1])
        plausible_kernel.warm_up()  # compiled (or loaded from the cache) before the first block
        self.refused = 0
        self.by_reason = dict.fromkeys(REASONS, 0)
        self.events: list[Event] = []
        self._unreported = dict.fromkeys(REASONS, 0)  # refusals since the last event, by reason
        self._pending = 0  # ... and in all
        self._reported_ns: int | None = None

    def run(
        self,
        block: AlignedSamples,
        update: Callable[[AlignedSamples], Estimates],
        flags: tuple[bool, bool],
        extras: tuple[np.ndarray, ...] = (),
    ) -> Estimates:
        """``update`` over the accepted samples of ``block``; one row per sample of ``block``.

        Args:
            update: the estimator's own update over a block. flags: (converged_force,
                converged_torque) before the block. extras: more arrays of the block's rows the
                estimator uses (quat_BE, p_BoEo_B), checked for finiteness.
        """
        ok = self.accepted(block, extras)
        if ok is None:
            return update(block)
        out = update(block.subset(ok)) if ok.any() else None
        return refused_rows(block.t_ns, ok, out, flags)

    def accepted(self, block: AlignedSamples, extras: tuple[np.ndarray, ...] = ()) -> np.ndarray | None:
        """None when every sample may be used (the usual case), else the (m,) mask of those that may."""
        if all_plausible(block.force_S, block.torque_S, block.R_EB, self.max_force, self.max_torque) and (
            not extras or all(np.isfinite(extra).all() for extra in extras)
        ):
            if self._pending and len(block):  # refusals held back by the interval: report them once it has passed
                self._report(int(block.t_ns[-1]))
            return None
        codes = refusal_codes(block.force_S, block.torque_S, block.R_EB, self.max_force, self.max_torque, extras)
        ok: np.ndarray = codes == 0
        if ok.all():
            return None
        for reason, count in zip(REASONS, np.bincount(codes, minlength=4)[1:].tolist()):
            self.by_reason[reason] += count
            self._unreported[reason] += count
            self._pending += count
        self.refused += int(np.count_nonzero(~ok))
        self._report(int(block.t_ns[np.flatnonzero(~ok)[-1]]))
        return ok

    def _report(self, t_ns: int) -> None:
        """The refusals not yet reported as one event, unless the last event is less than the interval ago."""
        if self._reported_ns is not None and t_ns - self._reported_ns < REFUSAL_REPORT_NS:
            return
        counts = {reason: n for reason, n in self._unreported.items() if n}
        new = self._pending
        why = {
            NON_FINITE: "NaN or inf in the force, torque or pose",
            NOT_A_ROTATION: f"R_EB not a rotation (‖R Rᵀ − I‖ > {ROTATION_TOLERANCE:g} or det ≤ 0)",
            BEYOND_THE_BOUND: f"beyond the bound (a force component above max_force = {self.max_force:g} N "
            f"or a torque component above max_torque = {self.max_torque:g} N·m)",
        }
        since = "" if self._reported_ns is None else " since the last report"
        message = (
            f"{self.source}: {new} sample{'s' if new > 1 else ''} refused{since}: "
            + "; ".join(f"{n} {why[reason]}" for reason, n in counts.items())
            + f"; {self.refused} in all, the estimate left as it was"
        )
        self.events.append(
            Event(t_ns, "sample_refused", message, {"count": self.refused, "new": new, "reasons": counts})
        )
        self._unreported = dict.fromkeys(REASONS, 0)
        self._pending = 0
        self._reported_ns = t_ns

    def drain_events(self) -> list[Event]:
        """The events since the last call."""
        out, self.events = self.events, []
        return out


class RefusesBadSamples:
    """What every estimator guarded by a ``SampleGuard`` (``self.guard``) reports, with stages
    ``self.force`` and ``self.torque`` that count their failed solves (``failed``)."""

    guard: SampleGuard
    force: Any
    torque: Any
    """The estimator's two stages: anything with a ``failed`` count (each estimator has its own stage type)."""

    @property
    def refused_samples(self) -> int:
        """Samples refused as bad input so far."""
        return self.guard.refused

    @property
    def failed_solves(self) -> int:
        """Samples whose solve failed (left out and marked not converged)."""
        return int(self.force.failed + self.torque.failed)

    def drain_events(self) -> list[Event]:
        """The events since the last call (EmitsEvents): ``sample_refused``."""
        return self.guard.drain_events()


def refused_rows(t_ns: np.ndarray, ok: np.ndarray, out: Estimates | None, flags: tuple[bool, bool]) -> Estimates:
    """Estimates for every row of a block from ``out``, the estimates of its accepted rows (``ok``).

    A refused row gets NaN contact wrench, no contact, and the convergence flags after the
    accepted row before it (``flags`` before the block when there is none).
    """
    m = len(ok)
    force, torque = np.full((m, 3), np.nan), np.full((m, 3), np.nan)
    contact = np.zeros(m, dtype=bool)
    conv_f, conv_t = np.full(m, flags[0], dtype=bool), np.full(m, flags[1], dtype=bool)
    if out is not None:
        force[ok], torque[ok], contact[ok] = out.contact_force_S, out.contact_torque_S, out.contact
        follows = np.cumsum(ok) - 1  # index in ``out`` of the accepted row at or before each row (-1: none)
        seen = follows >= 0
        conv_f[seen], conv_t[seen] = out.converged_force[follows[seen]], out.converged_torque[follows[seen]]
    return Estimates(t_ns, force, torque, contact, conv_f, conv_t)
