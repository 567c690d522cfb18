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

from hapticlab.sessions.live.drift import BIN_NS, MIN_OFFSET_N

PITCH_N_M = 0.05
"""A bin's residual may twist about its own line by this much, N·m, plus ``PATCH_M`` times its force. Two
point forces at different places twist: the estimator's own force error beside a tip contact does, and rls's
and batch's errors in a contact reach 0.045 N·m on demo seeds (kalman's in 60 s of random touches, 0.035). A
bias of about half a newton beside a 3 N tip contact 25 cm out, across it, exceeds it."""
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
CLEAR_BINS = 5
"""A hold ends after this many bins in a row (0.1 s) a touch can give: a bias near the bound, its residual
in and out of it with the noise, keeps the force off rather than flicker it on and off."""


class LeverWatch:
    """Tells a residual a touch can give from one it cannot, by its torque: it holds, it never re-identifies.

    Args:
        tool_axis_S: the tool's axis in S, from the sensor towards the tip (any length; zero: the lever arm is
            not read, the twist still is).

    ``add`` takes each block the primary estimator refined; ``reason`` then says why no touch gives the
    residual, from the first bin none could until ``CLEAR_BINS`` in a row one could ("" otherwise): the gate
    holds the force on it. What the residual is, it leaves to the drift watch (``drift.py``) once the tool
    turns: re-identifying a bias as soon as its torque shows it (a ramp 0.26 N in) gave the force back while
    the bias still drifted, and a contact then hid the rest (kalman: 0.65 N made up, 0.25 N held until the
    motion told).
    """

    def __init__(self, tool_axis_S: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> None:
        norm = math.hypot(*tool_axis_S)
        self.a = [v / norm for v in tool_axis_S] if norm > 0 else None
        self.reset()

    def reset(self) -> None:
        """Forget the bin in hand and the hold (after the drift watch's bias step, a re-arm)."""
        self.bin_start_ns: int | None = None
        self.total = [0.0] * 6
        self.count = 0
        self.reason = ""
        self.clear = 0  # bins in a row a touch can give, since the last that none could

    def add(self, t_ns: np.ndarray, force_S: np.ndarray, torque_S: np.ndarray, judge: bool) -> None:
        """One block: stamps (n,) ns, the residual force (n, 3) N and torque (n, 3) N·m in S; ``judge``: the
        estimator is known and its torque stage converged. Unjudged bins are only counted: a hold in hand stays
        (kalman's flag at the pose drops at every new pose, a bias does not go with it); ``reset`` ends it."""
        for t, f, m in zip(t_ns.tolist(), force_S.tolist(), torque_S.tolist()):
            if not all(map(math.isfinite, f + m)):
                continue
            if self.bin_start_ns is None:
                self.bin_start_ns = t
            elif t - self.bin_start_ns >= BIN_NS:
                if judge:
                    self._close()
                self.bin_start_ns, self.total, self.count = t, [0.0] * 6, 0
            total = self.total
            for k, v in enumerate(f + m):
                total[k] += v
            self.count += 1

    def _close(self) -> None:
        """Judge the bin in hand: ``reason`` set when no touch gives it, cleared after ``CLEAR_BINS`` that one can."""
        fx, fy, fz, mx, my, mz = (v / self.count for v in self.total)
        size = math.sqrt(fx * fx + fy * fy + fz * fz)
        self.clear += 1  # (until the bin is found to be none a touch gives)
        if self.clear >= CLEAR_BINS:
            self.reason = ""
        if size < MIN_OFFSET_N:
            return
        pitch = (mx * fx + my * fy + mz * fz) / size
        if abs(pitch) > PITCH_N_M + PATCH_M * size:
            self.reason = (
                f"residual not a contact's: it twists about its own line ({pitch:+.3f} N·m at {size:.2f} N: "
                "no single touch gives that; a force bias beside a contact)"
            )
            self.clear = 0
            return
        if self.a is None:
            return
        ax, ay, az = self.a
        cx, cy, cz = ay * fz - az * fy, az * fx - ax * fz, ax * fy - ay * fx  # a × F
        across = cx * cx + cy * cy + cz * cz
        if across < (ACROSS * size) ** 2:
            return
        lever = (cx * mx + cy * my + cz * mz) / across
        if lever < MIN_LEVER_M:
            where = "behind the sensor" if lever < 0 else f"within {MIN_LEVER_M * 1e3:.0f} mm of the sensor"
            self.reason = (
                f"residual not a contact's: it acts where nothing touches the tool ({size:.2f} N across it, "
                f"{lever * 1e3:.0f} mm along it, {where}: its zero moved, the weight model is off, or the "
                "estimator took a contact into its bias)"
            )
            self.clear = 0
