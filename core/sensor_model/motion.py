"""The recorded motion at each wrench sample, with its derivatives: what the sensor model follows.

:class:`Motion` holds the orientation of the flange at every wrench sample
and, with a time base in seconds, its angular velocity and acceleration and
the flange's acceleration; :func:`motion_from_poses` builds it from the
recorded poses (Savitzky–Golay derivatives, :func:`savgol` on an even grid,
:func:`savgol_t` on the samples' own times). A time-lag effect shifts it
(:meth:`Motion.shifted`).

Frames and units as everywhere (``hapticlab.core.frames``): ``R_EB`` maps B
into E, time s (or rows when the file's ``t`` counts them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hapticlab.core.frames import matrix_from_quat_wxyz, quat_conjugate, quat_multiply, quat_slerp

__all__ = ["Motion", "motion_from_poses", "savgol", "savgol_t"]


@dataclass(frozen=True)
class Motion:
    """The recorded motion at each wrench sample: what effects may use.

    Attributes:
        t: (n,) sample times on the sensor's clock: seconds, or row numbers when
            ``time_base`` is ``"index"`` (the file's ``t`` counts rows or poses).
        R_EB: (n, 3, 3) orientation of B in E (from the kinematics).
        quat_BE: (n, 4) the same as [w, x, y, z] quaternions of E in B, sign-continuous.
        w_E: (n, 3) angular velocity of E in B, expressed in E, rad/s; None
            without a time base.
        alpha_E: (n, 3) angular acceleration, rad/s²; None without a time base.
        a_B: (n, 3) acceleration of E's origin in B, m/s² (gravity excluded);
            None without positions or a time base.
        time_base: ``"seconds"`` or ``"index"``.
        rate_hz: samples per second (median), None with an index time base.
        t_ref: reference time of time-varying terms (the middle of the whole recording).
        shift: how far the kinematic quantities were shifted from the recording's, s.
        source: the recorded motion this one was shifted from (None: this is it).
        cache: terms of the prediction that depend on this motion and a few parameters, by an exact key
            (``ModelState.cached``; not an init field, so ``replace`` and ``subset`` start empty).
    """

    t: np.ndarray
    R_EB: np.ndarray
    quat_BE: np.ndarray
    w_E: np.ndarray | None = None
    alpha_E: np.ndarray | None = None
    a_B: np.ndarray | None = None
    time_base: str = "seconds"
    rate_hz: float | None = None
    t_ref: float = 0.0
    shift: float = 0.0
    source: Motion | None = None
    cache: dict[tuple[Any, ...], Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def has_time(self) -> bool:
        """True when ``t`` is in seconds and the derivatives exist."""
        return self.time_base == "seconds" and self.w_E is not None

    def subset(self, index: slice | np.ndarray) -> Motion:
        """The samples selected by a mask or index array (of a recorded motion, not a shifted one)."""
        if self.source is not None:
            raise ValueError("subset() of a shifted motion; take the subset of the recording, then shift")
        pick: Callable[[np.ndarray | None], np.ndarray | None] = lambda a: None if a is None else a[index]  # noqa: E731 (a one-line closure)
        return Motion(
            self.t[index],
            self.R_EB[index],
            self.quat_BE[index],
            pick(self.w_E),
            pick(self.alpha_E),
            pick(self.a_B),
            self.time_base,
            self.rate_hz,
            self.t_ref,
        )

    def shifted(self, dt: float) -> Motion:
        """The motion recorded at ``t + dt`` for each sample (slerp and linear interpolation; held at the ends).

        ``t`` itself is kept (it is the sensor's clock); only the kinematic
        quantities move. Shifts add up, and always interpolate the recording.
        """
        src = self.source if self.source is not None else self
        total = self.shift + float(dt)
        if total == 0.0:
            return src
        t = src.t
        at = np.clip(t + total, t[0], t[-1])
        k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
        span = t[k + 1] - t[k]
        u = np.clip(np.divide(at - t[k], span, out=np.zeros_like(at), where=span > 0), 0.0, 1.0)
        quat = quat_slerp(src.quat_BE[k], src.quat_BE[k + 1], u)
        lerp: Callable[[np.ndarray | None], np.ndarray | None] = (  # noqa: E731 (a one-line closure)
            lambda a: None if a is None else a[k] + u[:, None] * (a[k + 1] - a[k])
        )
        return Motion(
            t,
            matrix_from_quat_wxyz(quat).transpose(0, 2, 1),
            quat,
            lerp(src.w_E),
            lerp(src.alpha_E),
            lerp(src.a_B),
            src.time_base,
            src.rate_hz,
            src.t_ref,
            total,
            src,
        )


def _continuous(quat: np.ndarray) -> np.ndarray:
    """Quaternions with signs flipped so consecutive ones are on the same hemisphere."""
    dots = np.einsum("ij,ij->i", quat[1:], quat[:-1])
    flips = np.concatenate([[False], dots < 0])
    sign = np.where(np.logical_xor.accumulate(flips), -1.0, 1.0)
    return quat * sign[:, None]


def savgol(x: np.ndarray, window: int, deriv: int, dt: float, order: int = 3) -> np.ndarray:
    """Savitzky–Golay smoothing or derivative of (n, k) uniformly sampled columns.

    A least-squares polynomial of ``order`` over ``window`` (odd) samples
    centred on each sample, evaluated (its ``deriv``-th derivative) there; the
    first and last half-windows use the polynomial of the first and last full
    window (scipy's ``mode="interp"``). Plain numpy: scipy's own BLAS threads
    would then contend with numpy's for a small machine's cores.
    """
    n, half = len(x), window // 2
    s = np.arange(-half, half + 1, dtype=float)
    V = np.vander(s, order + 1, increasing=True)  # (window, order+1): 1, s, s², ...
    fit = np.linalg.pinv(V)  # rows: polynomial coefficients from the window's samples
    scale = float(np.prod(np.arange(1, deriv + 1))) / dt**deriv
    coeff = fit[deriv] * scale  # value of the deriv-th derivative at s = 0
    out = np.empty_like(x, dtype=float)
    # interior: a correlation with the coefficients, column by column
    from numpy.lib.stride_tricks import sliding_window_view

    windows = sliding_window_view(x, window, axis=0)  # (n - window + 1, k, window)
    out[half : n - half] = windows @ coeff
    # the edges: derivative of the first/last window's polynomial at each edge sample
    powers = np.arange(order + 1)
    for rows, block in ((slice(0, half), x[:window]), (slice(n - half, n), x[n - window :])):
        poly = fit @ block  # (order+1, k)
        at = s[:half] if rows.start == 0 else s[-half:]
        d = np.zeros((len(at), order + 1))
        for p in powers[deriv:]:
            d[:, p] = np.prod(np.arange(p - deriv + 1, p + 1)) * at ** (p - deriv)
        out[rows] = d @ poly / dt**deriv
    return out


def savgol_t(x: np.ndarray, t: np.ndarray, window: int, deriv: int, order: int = 3) -> np.ndarray:
    """Savitzky–Golay on the actual sample times: a least-squares polynomial in real time per window.

    Like :func:`savgol` (the same window of ``window`` samples centred on each
    sample, the first and last full window's polynomial at the edges), but the
    polynomial is fitted against the samples' own times ``t`` rather than a
    uniform grid, so jittered or unevenly spaced stamps give the right
    derivatives. Equal to :func:`savgol` on a uniform grid (to rounding).
    """
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    n, half = len(x), window // 2
    start = np.clip(np.arange(n) - half, 0, n - window)  # first sample of each sample's window
    idx = start[:, None] + np.arange(window)  # (n, window)
    centre = t[start + half]
    h = float(np.median(np.diff(t)))  # time unit of the fit (conditioning)
    u = (t[idx] - centre[:, None]) / h  # (n, window)
    V = u[:, :, None] ** np.arange(order + 1)  # (n, window, order+1)
    VtV = np.einsum("nwi,nwj->nij", V, V)
    # d^deriv/du^deriv of the polynomial at the sample's own time
    at = (t - centre) / h
    e = np.zeros((n, order + 1))
    for p in range(deriv, order + 1):
        e[:, p] = np.prod(np.arange(p - deriv + 1, p + 1)) * at ** (p - deriv)
    coef = np.linalg.solve(VtV, e[:, :, None])[:, :, 0]  # (n, order+1): (VᵀV)⁻¹ e
    weights = np.einsum("nwi,ni->nw", V, coef) / h**deriv  # (n, window)
    smoothed: np.ndarray = np.einsum("nw,nwk->nk", weights, x[idx])
    return smoothed


def motion_from_poses(
    t: np.ndarray,
    quat_BE: np.ndarray,
    p_BoEo_B: np.ndarray | None = None,
    time_base: str = "seconds",
    window_s: float = 0.04,
) -> Motion:
    """The recorded motion with its derivatives, from the poses at each sample.

    Derivatives (only with a time base in seconds) come from a centred
    Savitzky–Golay filter (cubic, ``window_s`` wide at the median sample
    period, at least 5 samples; fitted against the actual sample times when
    the stamps are not evenly spaced, :func:`savgol_t`): of the sign-continuous
    quaternion q = q_BE, giving ``ω_E = 2 vec(q* ⊗ q̇)`` and
    ``α_E = 2 vec(q* ⊗ q̈)`` (the term q̇* ⊗ q̇ is a scalar), and of the positions,
    giving a_B. Offline, so centred: no lag, and a cubic over a window much
    shorter than a move follows the motion's acceleration to within its jerk's
    variation over the window.

    Args:
        t: (n,) increasing sample times, s (or rows). quat_BE: (n, 4) [w, x, y, z].
        p_BoEo_B: (n, 3) flange positions in B, m, or None.
        time_base: ``"seconds"`` or ``"index"`` (then no derivatives).
        window_s: the filter's window, s.
    """
    t = np.asarray(t, dtype=float)
    quat = _continuous(np.asarray(quat_BE, dtype=float))
    quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    R_EB = matrix_from_quat_wxyz(quat).transpose(0, 2, 1)
    t_ref = 0.5 * (t[0] + t[-1]) if len(t) else 0.0
    if time_base != "seconds" or len(t) < 5:
        return Motion(t, R_EB, quat, time_base=time_base, t_ref=t_ref)
    dt = float(np.median(np.diff(t)))
    window = max(5, round(window_s / dt) | 1)
    if window > len(t):
        window = len(t) if len(t) % 2 else len(t) - 1
    steps = np.diff(t)
    sg: Callable[[np.ndarray, int], np.ndarray]
    if np.ptp(steps) <= 1e-6 * dt:  # evenly spaced: the uniform filter (a correlation, faster)
        sg = lambda x, d: savgol(x, window, d, dt)  # noqa: E731 (a one-line closure)
    else:
        sg = lambda x, d: savgol_t(x, t, window, d)  # noqa: E731 (a one-line closure)
    q_conj = quat_conjugate(sg(quat, 0))
    w_E = 2.0 * quat_multiply(q_conj, sg(quat, 1))[:, 1:]
    alpha_E = 2.0 * quat_multiply(q_conj, sg(quat, 2))[:, 1:]
    a_B = sg(np.asarray(p_BoEo_B, dtype=float), 2) if p_BoEo_B is not None else None
    return Motion(t, R_EB, quat, w_E, alpha_E, a_B, "seconds", 1.0 / dt, t_ref)
