"""``kalman``: the paper's cascade as Kalman filters, with drifting biases, Mahalanobis gating
and convergence from the covariance.

Force stage: x = [gravity_force_B, bias_force_S], C_k = [R_EB, I3].
Torque stage, at samples where the force stage has converged and accepted the
sample: x = [cog_S, bias_torque_S], C_k = [-skew(force_S - bias_force_S), I3]
(Δf with the force stage's bias after the same sample, as in ``rls``). The
model and the filter are in ``hapticlab.core.kalman``; what differs from the
paper's RLS:

* **Drift.** The biases are random walks (``bias_force_rw`` N/√s,
  ``bias_torque_rw`` N·m/√s) instead of constants; with ``bias_rate = true``
  each bias also gets a rate state (N/s, N·m/s) driven by
  ``bias_force_rate_rw`` / ``bias_torque_rate_rw``. Gravity and the centre of
  gravity stay constant. The time step of every prediction is the samples'
  own ``t_ns`` difference.
* **Noise in physical units.** R is the sensor's noise (``noise_force`` N,
  ``noise_torque`` N·m, per-axis std); the torque stage adds the force noise
  carried into its C_k through the centre of gravity.
* **Gating.** A sample whose innovation has a squared Mahalanobis distance
  eᵀ(C P Cᵀ + R)⁻¹e above the chi-square quantile of ``gate_probability``
  (3 degrees of freedom) is refused as contact. It does not update the stage,
  but time still propagates: the drift states' variance keeps growing through
  a long contact, so the gate reopens on a bias that has truly moved instead
  of locking out as the paper's fixed threshold does. A sample the force stage
  refuses is not given to the torque stage.
* **Convergence from the covariance.** A stage counts as converged when every
  parameter's standard deviation (sqrt diag P) is below a bound in physical
  units: ``converged_force_std`` (N) for gravity_force_B and bias_force_S;
  ``converged_torque_std`` (N·m) for bias_torque_S and for the torque a
  centre-of-gravity error can cause, std(cog_S)·|gravity_force_B|. A small
  step ‖Δx‖ (the paper's test) never counts, so repeated or barely varied
  poses cannot fake it; the flag is re-evaluated at every sample (it drops if
  a contact lasts so long that the bias is no longer known to the bound, ~15 s
  with the defaults). Identical repeated rows are still counted as
  independent readings: five copies of a pose make P √5 too optimistic.

Default drift intensities. The drift figure used is a thermal (warm-up) bias
drift of **0.5 N/min** (0.0083 N/s), the drift of hapticlab's drift scenario
and of the order of what strain-gauge sensors of the ATI Gamma / Net F/T class
show while they warm up (an order of magnitude, not a datasheet value: no
published ATI drift figure was at hand). The rule: the smallest random walk
that follows that drift with a lag of at most 5 % of the sensor noise. For a
random-walk bias measured with noise density √N (σ·√dt: 0.12 N at 1 kHz is
0.0038 N·√s), intensity q gives the bias estimate a time constant
τ = √N / q, a steady-state std √(q·√N) and a lag d·τ behind a drift d. With
**q = 0.005 N/√s**: τ = 0.76 s, std 4.4 mN (well below the 0.02 N convergence
bound), lag 6 mN (5 % of 0.12 N). A larger q follows faster drifts but lets
more of each contact's sub-threshold ramp into the bias and needs more
excitation to converge (q = 0.02: contact error 0.16 N instead of 0.12 N on
the test's indentations, convergence three times later); a smaller one lags
(q = 0.002: 16 mN). The torque default scales q by the Gamma SI-65-5's
torque-to-force range (5 N·m / 65 N = 0.077 m): **0.0004 N·m/√s**. Rate
states (off by default): the drift rate itself wanders by about its own size
over ~10 min, 0.0083 N/s / √600 s ≈ **3e-4 N/s/√s**, and 2.5e-5 N·m/s/√s
for torque.

Priors (zero mean): ``prior_force_std`` 20 N (gravity and force bias: a
surgical tool's weight plus a sensor bias), ``prior_cog_std`` 0.5 m,
``prior_torque_std`` 5 N·m. They only hold the parameters no pose has
determined yet; far wider priors make the first samples ill-conditioned (at
50 N the fast and the reference filter differ by 2e-9 N before convergence,
at 20 N by 2e-10 N).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from hapticlab.core import hookimpl
from hapticlab.core.frames import skew_stack
from hapticlab.core.kalman import KalmanStage
from hapticlab.core.model import contact_wrench, named_params
from hapticlab.core.types import AlignedSamples, Estimates
from scipy.stats import chi2

BIAS_RATE_PRIOR_FORCE = 0.025
"""Prior std of the force-bias rate, N/s (three times the 0.5 N/min drift figure)."""
BIAS_RATE_PRIOR_TORQUE = 0.002
"""Prior std of the torque-bias rate, N·m/s (the force figure times 0.077 m)."""


def _axes(key: str, value) -> np.ndarray:
    """A positive std per axis from one number or three; ValueError naming the option."""
    array = np.array(value, dtype=float) if not isinstance(value, bool) else np.array(np.nan)
    if array.ndim == 0:
        array = np.full(3, float(array))
    if array.shape != (3,) or not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{key}: must be a positive number or 3 positive numbers, got {value!r}")
    return array


class KalmanEstimator:
    """Cascaded Kalman filters of the non-contact wrench, with drifting biases.

    Args:
        noise_force: sensor force noise, N, std per axis (one number or three).
        noise_torque: sensor torque noise, N·m, std per axis (one number or three).
        bias_force_rw: random-walk intensity of bias_force_S, N/√s (0: constant bias).
        bias_torque_rw: random-walk intensity of bias_torque_S, N·m/√s.
        bias_rate: add bias-rate states (N/s, N·m/s) to both stages.
        bias_force_rate_rw: random-walk intensity of the force-bias rate, N/s/√s.
        bias_torque_rate_rw: the same for the torque-bias rate, N·m/s/√s.
        gate_probability: a sample whose innovation lies outside this
            probability mass of the predicted distribution (chi-square, 3 dof)
            is refused as contact; 1 never refuses.
        converged_force_std: bound on the std of gravity_force_B and bias_force_S, N.
        converged_torque_std: bound on the std of bias_torque_S and of
            std(cog_S)·|gravity_force_B|, N·m.
        prior_force_std: prior std of gravity_force_B and bias_force_S, N.
        prior_cog_std: prior std of cog_S, m.
        prior_torque_std: prior std of bias_torque_S, N·m.
        implementation: "auto" (the unrolled filter, or filterpy's with
            bias_rate), "fast" or "filterpy" (the reference, ~15× slower).
        payload_change_s: after this long (s) of continuous refusal by the
            force stage, test whether the refused residual is a change of the
            tool's weight (a payload change); if so, re-open gravity and the
            centre of gravity (0 disables the test).
        warm_start: path to a JSON file written from ``state()`` (e.g. a
            session's ``<recording>.calibration.json``): start from its x and P.

    Attributes:
        force, torque: the two KalmanStage stages.
        converged_force, converged_torque: the stages' flags after the last sample.
        first_converged_force, first_converged_torque: index of the sample at
            which each flag first became true (None until then).
        samples: samples seen.
        gate2: the gate on the squared Mahalanobis distance.
    """

    def __init__(
        self,
        noise_force: float | list[float] = 0.12,
        noise_torque: float | list[float] = 0.01,
        bias_force_rw: float = 0.005,
        bias_torque_rw: float = 0.0004,
        bias_rate: bool = False,
        bias_force_rate_rw: float = 3e-4,
        bias_torque_rate_rw: float = 2.5e-5,
        gate_probability: float = 0.9999,
        converged_force_std: float = 0.02,
        converged_torque_std: float = 0.002,
        prior_force_std: float = 20.0,
        prior_cog_std: float = 0.5,
        prior_torque_std: float = 5.0,
        implementation: str = "auto",
        payload_change_s: float = 1.0,
        warm_start: str = "",
    ):
        noise_force = _axes("noise_force", noise_force)
        noise_torque = _axes("noise_torque", noise_torque)
        for key, value in (("bias_force_rw", bias_force_rw), ("bias_torque_rw", bias_torque_rw),
                           ("bias_force_rate_rw", bias_force_rate_rw),
                           ("bias_torque_rate_rw", bias_torque_rate_rw)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{key}: must be a finite number >= 0, got {value!r}")
        for key, value in (("converged_force_std", converged_force_std),
                           ("converged_torque_std", converged_torque_std),
                           ("prior_force_std", prior_force_std), ("prior_cog_std", prior_cog_std),
                           ("prior_torque_std", prior_torque_std)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{key}: must be a finite number > 0, got {value!r}")
        if not (isinstance(gate_probability, (int, float)) and 0 < gate_probability <= 1):
            raise ValueError(f"gate_probability: must be in (0, 1], got {gate_probability!r}")
        if not isinstance(bias_rate, bool):
            raise ValueError(f"bias_rate: must be true or false, got {bias_rate!r}")  # noqa: TRY004 (options: ValueError)
        if implementation not in ("auto", "fast", "filterpy"):
            raise ValueError(f"implementation: must be 'auto', 'fast' or 'filterpy', got {implementation!r}")
        if implementation == "fast" and bias_rate:
            raise ValueError("implementation: 'fast' has no bias-rate states; use 'auto' or 'filterpy'")
        if not (isinstance(payload_change_s, (int, float)) and math.isfinite(payload_change_s)
                and payload_change_s >= 0):
            raise ValueError(f"payload_change_s: must be a finite number >= 0, got {payload_change_s!r}")
        if not isinstance(warm_start, str):
            raise ValueError(f"warm_start: must be a path (string), got {warm_start!r}")  # noqa: TRY004

        self.bias_rate = bias_rate
        self.method = None if implementation == "auto" else implementation
        self.gate2 = math.inf if gate_probability == 1 else float(chi2.ppf(gate_probability, 3))
        self.converged_force_std = float(converged_force_std)
        self.converged_torque_std = float(converged_torque_std)
        rate_f = [bias_force_rate_rw] * 3 if bias_rate else None
        rate_t = [bias_torque_rate_rw] * 3 if bias_rate else None
        prior_f = [prior_force_std] * 6 + ([BIAS_RATE_PRIOR_FORCE] * 3 if bias_rate else [])
        prior_t = [prior_cog_std] * 3 + [prior_torque_std] * 3 + ([BIAS_RATE_PRIOR_TORQUE] * 3 if bias_rate else [])
        self.force = KalmanStage(prior_f, [bias_force_rw] * 3, noise_force, bias_rate_rw=rate_f)
        self.torque = KalmanStage(prior_t, [bias_torque_rw] * 3, noise_torque, cross_noise=noise_force,
                                  bias_rate_rw=rate_t)
        self.converged_force = False
        self.converged_torque = False
        self.first_converged_force: int | None = None
        self.first_converged_torque: int | None = None
        self.samples = 0
        self._last_t_ns: int | None = None
        self.noise_force = noise_force
        self.prior_f = np.array(prior_f, dtype=float)
        self.prior_t = np.array(prior_t, dtype=float)
        self.payload_change_ns = int(round(payload_change_s * 1e9))
        self.events: list[tuple[int, str, str]] = []
        self.payload_changes = 0
        self._refused: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (t_ns, e_S, R_EB) of the run
        self._refused_since: int | None = None  # t_ns of the run's first refused sample
        self._accepted_in_run = 0  # consecutive accepted samples (a run survives a few)
        self._run_tested_full = False  # the run's whole window was tested (negative)
        if warm_start:
            self.load_state(warm_start)

    def update_block(self, block: AlignedSamples) -> Estimates:
        """Filter a block of aligned samples, in order."""
        m = len(block)
        if m == 0:
            empty = np.zeros((0, 3))
            flags = np.zeros(0, dtype=bool)
            return Estimates(block.t_ns, empty, empty.copy(), flags, flags.copy(), flags.copy())
        force_S, torque_S, R_EB = block.force_S, block.torque_S, block.R_EB
        t_ns = np.asarray(block.t_ns, dtype=np.int64)
        dt_ns = np.empty(m, dtype=np.int64)
        dt_ns[0] = 0 if self._last_t_ns is None else t_ns[0] - self._last_t_ns
        dt_ns[1:] = t_ns[1:] - t_ns[:-1]
        dt = np.maximum(dt_ns, 0) * 1e-9  # s; a repeated or reversed stamp adds no time
        self._last_t_ns = int(t_ns[-1])
        usable = block.usable

        x_before = self.force.x[:6].copy()
        run_f = self.force.run(force_S, R_EB, dt, usable, self.gate2, self.method)
        conv_f = run_f.D[:, :6].max(axis=1) < self.converged_force_std ** 2
        A_t = -skew_stack(force_S - run_f.X[:, 3:6])  # C_k = [-skew(Δf), I3]
        run_t = self.torque.run(torque_S, A_t, dt, usable & conv_f & ~run_f.gated, self.gate2, self.method)
        weight2 = (run_f.X[:, :3] ** 2).sum(axis=1)  # |gravity_force_B|², N²
        bound2 = self.converged_torque_std ** 2
        conv_t = (run_t.D[:, :3].max(axis=1) * weight2 < bound2) & (run_t.D[:, 3:6].max(axis=1) < bound2)
        contact_force_S, contact_torque_S = contact_wrench(force_S, torque_S, R_EB, run_f.X[:, :6], run_t.X[:, :6])

        self.converged_force, self.converged_torque = bool(conv_f[-1]), bool(conv_t[-1])
        if self.payload_change_ns > 0:
            self._watch_payload(t_ns, force_S, torque_S, R_EB, usable, run_f, x_before)
        if self.first_converged_force is None and conv_f.any():
            self.first_converged_force = self.samples + int(np.argmax(conv_f))
        if self.first_converged_torque is None and conv_t.any():
            self.first_converged_torque = self.samples + int(np.argmax(conv_t))
        self.samples += m
        return Estimates(
            t_ns=block.t_ns,
            contact_force_S=contact_force_S,
            contact_torque_S=contact_torque_S,
            contact=run_f.gated | run_t.gated,
            converged_force=conv_f,
            converged_torque=conv_t,
        )

    # ------------------------------------------------------------------ payload change (issue 4, item 6)

    PAYLOAD_WINDOW_RUNS = 3
    """The refused window tested is the run from its start, at most this many times payload_change_s."""
    PAYLOAD_FIT_RATIO = 2.0
    """The gravity-change fit must leave a mean squared residual below this many noise variances."""
    PAYLOAD_MAX_TILT = 0.25
    """rad: the fitted weight change must be along the identified weight (gravity) within this angle."""
    PAYLOAD_RUN_BREAK = 10
    """This many consecutive accepted samples end a refusal run (isolated ones do not)."""

    def _watch_payload(self, t_ns, force_S, torque_S, R_EB, usable, run_f, x_before) -> None:
        """Track the force stage's refusal run; test it for a payload change once it is long enough.

        While the force stage refuses, its state does not move (only P grows), so the refused
        residual e_k = force_S - R_EB·g - b is taken at the state each refused sample saw. A
        payload change adds Δg along gravity in B: e_k = R_EB·Δg + noise, so Δg = mean(R_EBᵀ e_k)
        (R orthonormal) and the fit's residual is at noise level. A contact with a ramp, a
        force fixed in S, or one along another direction leaves a larger residual or a Δg off
        the vertical.
        """
        gated = run_f.gated
        if not gated.any() and self._refused_since is None:
            return
        # the state each sample was predicted from: the previous row of X (x_before for the first)
        X_prev = np.vstack([x_before[None, :], run_f.X[:-1, :6]])
        e = force_S - np.einsum("kij,kj->ki", R_EB, X_prev[:, :3]) - X_prev[:, 3:6]
        start = 0
        for k in np.flatnonzero(usable):
            if gated[k]:
                if self._refused_since is None:
                    self._refused_since, self._refused, self._run_tested_full = int(t_ns[k]), [], False
                    start = k
                self._accepted_in_run = 0
            elif self._refused_since is not None:
                self._accepted_in_run += 1
                if self._accepted_in_run >= self.PAYLOAD_RUN_BREAK:
                    self._refused_since, self._refused = None, []
                    start = k + 1
        if self._refused_since is None:
            return
        # the window is the run from its first refused sample on (its onset included: a contact
        # ramps up, a payload is a step), at most PAYLOAD_WINDOW_RUNS·payload_change_s long
        newest = self._refused_since + self.PAYLOAD_WINDOW_RUNS * self.payload_change_ns
        keep = np.zeros(len(t_ns), dtype=bool)
        keep[start:] = gated[start:] & (t_ns[start:] <= newest)
        if keep.any():
            self._refused.append((t_ns[keep].copy(), e[keep], R_EB[keep].copy(), force_S[keep].copy(),
                                  torque_S[keep].copy()))
        t_last = int(t_ns[-1])
        if t_last - self._refused_since < self.payload_change_ns or not self._refused or self._run_tested_full:
            return
        self._run_tested_full = t_last >= newest  # the whole window seen: no further test in this run
        E, R, F, TQ = (np.concatenate([r[i] for r in self._refused]) for i in (1, 2, 3, 4))
        if len(E) < 10:
            return
        dg = np.einsum("kji,kj->i", R, E) / len(E)  # least squares of e = R_EB·Δg
        resid = E - R @ dg
        ratio = float(np.mean(resid ** 2 / self.noise_force ** 2))
        g = self.force.x[:3]
        gn, dn = float(np.linalg.norm(g)), float(np.linalg.norm(dg))
        vertical = gn > 0 and dn > 0 and abs(float(g @ dg)) >= math.cos(self.PAYLOAD_MAX_TILT) * gn * dn
        if ratio < self.PAYLOAD_FIT_RATIO and vertical:
            self._reopen_payload(F, TQ, R)
            message = (f"kalman: payload change of {dn:.3g} N ({dn / 9.81 * 1000:.0f} g) "
                       f"after {(t_last - self._refused_since) * 1e-9:.2f} s of refused samples; "
                       f"gravity and centre of gravity re-opened")
            self.events.append((t_last, "payload_change", message))
            self._refused_since, self._refused, self._accepted_in_run = None, [], 0

    def _reopen_payload(self, force_S, torque_S, R_EB) -> None:
        """Put gravity's and the cog's covariance back to the prior, then replay the refused window.

        The replay gives both stages the window's samples (no time step: they are
        already behind the stages' clock), so the new weight and centre of gravity
        are known as soon as the change is recognised, as far as the window's
        orientations determine them.
        """
        self.payload_changes += 1
        for stage, prior in ((self.force, self.prior_f), (self.torque, self.prior_t)):
            P = stage.P.copy()
            P[:3, :] = 0.0
            P[:, :3] = 0.0
            P[:3, :3] = np.diag(prior[:3] ** 2)
            stage.P = P
        m = len(force_S)
        zeros, ones = np.zeros(m), np.ones(m, dtype=bool)
        run_f = self.force.run(force_S, R_EB, zeros, ones, self.gate2, self.method)
        accepted = ~run_f.gated
        A_t = -skew_stack(force_S - run_f.X[:, 3:6])
        self.torque.run(torque_S, A_t, zeros, accepted, self.gate2, self.method)

    def drain_events(self) -> list[tuple[int, str, str]]:
        """The events since the last call, (t_ns, kind, message); the session loop records them."""
        out, self.events = self.events, []
        return out

    # ------------------------------------------------------------------ warm start (issue 4, item 7)

    def state(self) -> dict:
        """A JSON-serialisable snapshot: estimator name, x and P of both stages, flags, last t_ns."""
        return {
            "estimator": "kalman",
            "bias_rate": self.bias_rate,
            "force": {"x": self.force.x.tolist(), "P": self.force.P.tolist()},
            "torque": {"x": self.torque.x.tolist(), "P": self.torque.P.tolist()},
            "converged_force": self.converged_force,
            "converged_torque": self.converged_torque,
            "t_ns": self._last_t_ns,
            "params": self.params(),
        }

    def load_state(self, source: str | Path | dict) -> None:
        """Start from a ``state()`` (a dict or a JSON file); ValueError("warm_start: ...") if unusable."""
        where = "the given state"
        if not isinstance(source, dict):
            where = str(source)
            try:
                source = json.loads(Path(source).read_text())
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ValueError(f"warm_start: cannot read {where}: {exc}") from None
        if not isinstance(source, dict) or source.get("estimator") != "kalman":
            name = source.get("estimator") if isinstance(source, dict) else None
            raise ValueError(f"warm_start: {where} is not a kalman state (estimator {name!r})")
        if bool(source.get("bias_rate")) != self.bias_rate:
            raise ValueError(f"warm_start: {where} has bias_rate={source.get('bias_rate')!r}, "
                             f"this estimator {self.bias_rate}")
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
            if not np.allclose(P, P.T, rtol=1e-9, atol=1e-15) or np.linalg.eigvalsh((P + P.T) / 2).min() <= 0:
                raise ValueError(f"warm_start: {where}: {key} stage's P is not symmetric positive definite")
            loaded.append((stage, x, (P + P.T) / 2))
        for stage, x, P in loaded:
            stage.x, stage.P = x, P

    def params(self) -> dict[str, list[float]]:
        """Identified parameters with physical names (SI units); with bias_rate also the bias rates."""
        out = named_params(self.force.x[:6], self.torque.x[:6])
        if self.bias_rate:
            out["bias_force_rate_S"] = self.force.x[6:9].tolist()  # N/s
            out["bias_torque_rate_S"] = self.torque.x[6:9].tolist()  # N·m/s
        return out

    def force_parameter_std(self) -> np.ndarray:
        """(6,) standard deviation of [gravity_force_B, bias_force_S], N: sqrt of diag P_force."""
        return np.sqrt(np.diag(self.force.P)[:6])

    def torque_parameter_std(self) -> np.ndarray:
        """(6,) standard deviation of [cog_S (m), bias_torque_S (N·m)]: sqrt of diag P_torque."""
        return np.sqrt(np.diag(self.torque.P)[:6])

    def cov_diag(self) -> list[float]:
        """Diagonal of P for the force stage then the torque stage (12 values; 18 with bias_rate)."""
        return np.concatenate([np.diag(self.force.P), np.diag(self.torque.P)]).tolist()


@hookimpl
def register_estimators(register):
    register("kalman", KalmanEstimator)
