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

import math

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

        run_f = self.force.run(force_S, R_EB, dt, usable, self.gate2, self.method)
        conv_f = run_f.D[:, :6].max(axis=1) < self.converged_force_std ** 2
        A_t = -skew_stack(force_S - run_f.X[:, 3:6])  # C_k = [-skew(Δf), I3]
        run_t = self.torque.run(torque_S, A_t, dt, usable & conv_f & ~run_f.gated, self.gate2, self.method)
        weight2 = (run_f.X[:, :3] ** 2).sum(axis=1)  # |gravity_force_B|², N²
        bound2 = self.converged_torque_std ** 2
        conv_t = (run_t.D[:, :3].max(axis=1) * weight2 < bound2) & (run_t.D[:, 3:6].max(axis=1) < bound2)
        contact_force_S, contact_torque_S = contact_wrench(force_S, torque_S, R_EB, run_f.X[:, :6], run_t.X[:, :6])

        self.converged_force, self.converged_torque = bool(conv_f[-1]), bool(conv_t[-1])
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
