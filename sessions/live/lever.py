"""Where the residual acts: a contact touches the tool at a point, a sensor's zero moving acts nowhere.

A contact pushes on the tool at a point ``r_S`` (its tip, its shaft), so the torque it adds about the
sensor's origin is ``τ = r_S × F``. Two things follow that no motion is needed to see:

* **no twist along the force**: ``τ · F = 0``. The torque's part along the force's own line (its pitch,
  ``τ·F/|F|``, N·m) is zero for a touch at a single point, whatever the tool's shape or the touch's
  place. A force bias that appears beside a real contact (the contact's torque, the bias's none) has one.
* **a lever arm**: a tool along the unit axis ``a`` (``haptic.tool_axis``) is touched at ``r_S ≈ s·a``, so a
  force with a part across the tool (``a × F``) has a torque that tells how far along the tool it acts,
  ``s = (a × F)·τ / |a × F|²``, m. The sensor's own body and the tool's adapter are within ``MIN_LEVER_M``
  of its origin; a force across the tool that acts nearer (or behind the sensor) is not a contact: a force
  bias, which has no torque, gives ``s ≈ 0``.

:class:`LeverWatch` takes the primary estimator's residual (its contact force and torque) in bins of
``drift.BIN_NS`` and judges each bin once the torque stage has converged (before, the residual torque
holds the torque parameters' error). The drift watch (``drift.py``) needs the tool to turn; this does
not, but needs the residual torque: it catches a bias drifting on a still or slowly turning tool, or one
growing during a contact, and tells nothing of a push along the tool's axis through the sensor's origin.

What it cannot tell from a sensor fault, and holds: a contact with a twist about its own line (a
screwdriver's push and turn; a grasped needle pushed and rolled), and one within ``MIN_LEVER_M`` of the
sensor. docs/safety.md says so, with the rule's measured price.
"""

from __future__ import annotations

import math

import numpy as np

from hapticlab.core.types import Estimates
from hapticlab.sessions.live.drift import BIN_NS, MIN_OFFSET_N

PITCH_N_M = 0.03
"""A bin's residual may twist about its own line by this much, N·m, plus ``PATCH_M`` times its force: the
estimators' torque error in free motion (a bin's mean; rls, kalman on the demo: under 0.005 N·m) and a
margin, for kalman's residual in a long touch (its force bias takes a little of the touch in: at 0.02 N·m
plus 0.004 m·F it held 7 % of the touching time of 60 s of random touches, here 0.7 %). A 0.4 N bias beside
a 3 N tip contact 25 cm out, across it, exceeds it."""
PATCH_M = 0.003
"""...per newton of the residual, m: a touch spread over a patch (a jaw, a blunt tip) a few millimetres wide
twists by up to its half-width times the force."""
MIN_LEVER_M = 0.05
"""Nothing touches the tool within this distance of the sensor's origin along its axis, m: the sensor's body
and the tool's adapter are there. Demo contacts act 0.25 m out (the tip); a force bias, at 0 ± 0.04 m (the
torque error over a 0.2-0.5 N force)."""
ACROSS = math.sin(math.radians(45.0))
"""The lever arm is read only for a force at least 45° off the tool's axis (its part across the tool at least
this share): a push along the tool, with the axis stated a few degrees off, would read as a short lever."""
SENSOR_BINS = 5
"""A residual with no lever arm this many bins in a row (0.1 s) is a bias, to re-identify: kalman's residual
just after a touch's release can be one for 40-60 ms (the touch it took into its bias coming back out), held
but not worth re-opening the bias for."""
CLEAR_BINS = 5
"""A hold ends after this many bins in a row (0.1 s) a touch can give: a bias near the bound, its residual
in and out of it with the noise, keeps the force off rather than flicker it on and off."""


class LeverWatch:
    """Tells a residual a touch can give from one it cannot, by its torque.

    Args:
        tool_axis_S: the tool's axis in S (any length; zero: the lever arm is not read, the twist still is).

    ``add`` takes each block the primary estimator refined and returns ``"sensor"`` when the residual acted
    nearer the sensor than half the tool's centre of gravity (``cog_m``) for ``SENSOR_BINS`` bins (a bias:
    re-identify it), else ""; ``reason`` says why no touch gives
    the residual, from the first bin none could until ``CLEAR_BINS`` in a row one could ("" otherwise): the
    gate holds the force on it.
    """

    def __init__(self, tool_axis_S: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> None:
        norm = math.sqrt(sum(v * v for v in tool_axis_S))
        self.a = [v / norm for v in tool_axis_S] if norm > 0 else None
        self.cog_m = 0.0  # the estimated centre of gravity's distance along the axis, m (``gate``; 0: unknown)
        self.reset()

    def reset(self) -> None:
        """Forget the bin in hand and the verdicts (after a bias step was acted on)."""
        self.bin_start_ns: int | None = None
        self.total = [0.0] * 6
        self.count = 0
        self.reason = ""
        self.short = 0  # bins in a row with no lever arm
        self.clear = 0  # bins in a row a touch can give, since the last that none could
        self.offset_S = np.zeros(3)  # the newest judged bin's force, N

    def on_estimates(self, est: Estimates, params: dict[str, list[float]] | None, judge: bool) -> bool:
        """One block of the primary estimator's output, with its parameters (``cog_S``: where a weight model that
        is off acts), judged when ``judge`` and its torque stage has converged: True on a bias verdict."""
        if params is not None and "cog_S" in params and self.a is not None:
            self.cog_m = float(np.dot(params["cog_S"], self.a))
        judge = judge and bool(est.converged_torque[-1])
        return self.add(est.t_ns, est.contact_force_S, est.contact_torque_S, judge) == "sensor"

    def add(self, t_ns: np.ndarray, force_S: np.ndarray, torque_S: np.ndarray, judge: bool) -> str:
        """One block: stamps (n,) ns, the residual force (n, 3) N and torque (n, 3) N·m in S; ``judge``: the
        torque stage is converged (else the bins are only counted). The verdict of the bins it closed."""
        verdict = ""
        for t, f, m in zip(t_ns.tolist(), force_S.tolist(), torque_S.tolist()):
            if not all(map(math.isfinite, f + m)):
                continue
            if self.bin_start_ns is None:
                self.bin_start_ns = t
            elif t - self.bin_start_ns >= BIN_NS:
                verdict = (self._close() if judge else "") or verdict
                self.bin_start_ns, self.total, self.count = t, [0.0] * 6, 0
            total = self.total
            for k, v in enumerate(f + m):
                total[k] += v
            self.count += 1
        if not judge:
            self.reason, self.short = "", 0
        return verdict

    def _close(self) -> str:
        """Judge the bin in hand: set ``reason``; "sensor" once no lever arm held for ``SENSOR_BINS``."""
        fx, fy, fz, mx, my, mz = (v / self.count for v in self.total)
        size = math.sqrt(fx * fx + fy * fy + fz * fz)
        self.clear += 1  # (until the bin is found to be none a touch gives)
        if self.clear >= CLEAR_BINS:
            self.reason = ""
        if size < MIN_OFFSET_N:
            self.short = 0
            return ""
        pitch = (mx * fx + my * fy + mz * fz) / size
        if abs(pitch) > PITCH_N_M + PATCH_M * size:
            self.reason = (
                f"residual not a contact's: it twists about its own line ({pitch:+.3f} N·m at {size:.2f} N: "
                "no single touch gives that; a force bias beside a contact)"
            )
            self.short = self.clear = 0
            return ""
        if self.a is None:
            return ""
        ax, ay, az = self.a
        cx, cy, cz = ay * fz - az * fy, az * fx - ax * fz, ax * fy - ay * fx  # a × F
        across = cx * cx + cy * cy + cz * cz
        if across < (ACROSS * size) ** 2:
            self.short = 0
            return ""
        lever = (cx * mx + cy * my + cz * mz) / across
        if lever >= MIN_LEVER_M:
            self.short = 0
            return ""
        # (a weight model that is off, a pose late or a mass wrong, acts at the centre of gravity: only a residual
        # nearer the sensor than half-way to it counts towards a bias; the hold is the same, and its message names
        # every cause: kalman's residual of a force bias acts 10-30 mm out, the centre of gravity 43 mm)
        at_sensor = lever < 0.5 * (self.cog_m if self.cog_m > 0 else MIN_LEVER_M)
        self.reason = (
            f"residual not a contact's: it acts where nothing touches the tool ({size:.2f} N across it, "
            f"{lever * 1e3:.0f} mm along it, within {MIN_LEVER_M * 1e3:.0f} mm of the sensor: its zero moved, the "
            "weight model is off, or the estimator took a contact into its bias)"
        )
        self.offset_S = np.array([fx, fy, fz])
        self.short, self.clear = self.short + 1 if at_sensor else 0, 0
        return "sensor" if self.short >= SENSOR_BINS else ""
