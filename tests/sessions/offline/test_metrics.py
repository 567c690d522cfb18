"""The compensation metrics (``sessions/offline/metrics.py``) against their definitions, on seeded physical data.

Every expected value comes from the distribution the data were drawn from,
not from the code under test; every tolerance is five standard errors of the
estimate for the sample size used (so a correct implementation fails about
once in 1.7 million runs per check, and the seeds are fixed anyway).

Standard errors for n samples of N(0, σ): the RMS (and the Std) has a relative
standard error 1/√(2n); the MAE, whose expectation is σ·√(2/π), has
√(π/2 − 1)/√n ≈ 0.756/√n.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import static_model_stream
from scipy.stats import norm

from hapticlab.core.types import first_true
from hapticlab.plugins.estimators.rls import RLSEstimator
from hapticlab.sessions.offline.compensate import run_estimator
from hapticlab.sessions.offline.metrics import (
    error_stats,
    mae,
    mae_compensation_pct,
    max_ae,
    norm_ratio,
    rms,
    rms_after_convergence,
    scored_rows,
    std,
)
from hapticlab.sessions.recording.stream import Stream

SIGMA_F = np.array([0.12, 0.12, 0.06])
"""The paper set-up's force noise per axis, N."""
MAE_OVER_SIGMA = math.sqrt(2.0 / math.pi)
"""E|x| / σ for x ~ N(0, σ)."""


def rms_tolerance(n: int) -> float:
    """Five relative standard errors of an RMS (or Std) estimated from n Gaussian samples."""
    return 5.0 / math.sqrt(2.0 * n)


def mae_tolerance(n: int) -> float:
    """Five relative standard errors of an MAE estimated from n zero-mean Gaussian samples."""
    return 5.0 * math.sqrt(math.pi / 2.0 - 1.0) / math.sqrt(n)


def folded_normal_mean(mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """E|x| for x ~ N(mu, sigma): the MAE of a constant offset mu read through Gaussian noise."""
    return sigma * MAE_OVER_SIGMA * np.exp(-(mu**2) / (2 * sigma**2)) + mu * (1 - 2 * norm.cdf(-mu / sigma))


def test_rms_std_and_mae_of_sensor_noise_are_its_sigma():
    n = 200_000
    noise = np.random.default_rng(7).normal(0.0, SIGMA_F, (n, 3))
    assert np.all(np.abs(rms(noise) / SIGMA_F - 1) < rms_tolerance(n)), rms(noise)
    assert np.all(np.abs(std(noise) / SIGMA_F - 1) < rms_tolerance(n)), std(noise)
    assert np.all(np.abs(mae(noise) / (SIGMA_F * MAE_OVER_SIGMA) - 1) < mae_tolerance(n)), mae(noise)
    # one axis at a time gives one number
    assert rms(noise[:, 2]).shape == () and abs(rms(noise[:, 2]) / SIGMA_F[2] - 1) < rms_tolerance(n)


def test_rms_counts_an_uncompensated_bias_and_std_does_not():
    """A reading left with a 0.3 N bias: RMS² = bias² + σ², Std = σ."""
    n = 100_000
    bias = np.array([0.3, -0.3, 0.0])
    reading = bias + np.random.default_rng(8).normal(0.0, SIGMA_F, (n, 3))
    expected = np.sqrt(bias**2 + SIGMA_F**2)
    # the mean square's relative standard error is below √2/√n with an offset too (variance 2σ⁴ + 4b²σ²,
    # over (b² + σ²)² ≤ 2 / n): the RMS's half that
    assert np.all(np.abs(rms(reading) / expected - 1) < rms_tolerance(n)), rms(reading)
    assert np.all(np.abs(std(reading) / SIGMA_F - 1) < rms_tolerance(n))


def test_max_ae_of_bounded_noise_reaches_its_bound():
    """Uniform noise on [−a, a]: Max AE ≤ a, and above a·(1 − 1e-4) but with chance (1 − 1e-4)^n = e^-10."""
    n = 100_000
    a = np.array([0.5, 0.25, 0.05])
    noise = np.random.default_rng(9).uniform(-a, a, (n, 3))
    assert np.all(max_ae(noise) <= a) and np.all(max_ae(noise) >= a * (1 - 1e-4)), max_ae(noise)
    # and it is of |x|: flipping the sign of every sample changes nothing
    assert np.array_equal(max_ae(-noise), max_ae(noise))
    # the MAE of uniform noise is a / 2 (relative standard error 1/√(3n))
    assert np.all(np.abs(mae(noise) / (a / 2) - 1) < 5 / math.sqrt(3 * n))


def test_paper_table_of_a_held_tool_compensated_with_its_true_parameters():
    """The tool held still: the raw reading is its weight and the sensor bias (a constant) plus noise, the
    compensated one the noise alone. Before: MAE = E|c + noise| (folded normal), Std = σ; after: MAE = σ·√(2/π),
    Std = σ, Max AE between 3σ and 6σ (outside with chance e^-27 and 4e-5 at most); MAE compensation % as defined."""
    n = 20_000
    constant = np.array([5.0, 2.7, 1.1])  # N, the paper set-up's force bias
    noise = np.random.default_rng(10).normal(0.0, SIGMA_F, (n, 3))
    raw = constant + noise
    compensated = raw - constant
    table = error_stats(raw, compensated, ("fx", "fy", "fz"))
    assert list(table) == ["fx", "fy", "fz"]
    for k, axis in enumerate(table):
        row, sigma = table[axis], SIGMA_F[k]
        mae_before = float(folded_normal_mean(constant[k], sigma))
        mae_after = sigma * MAE_OVER_SIGMA
        # the raw MAE is the constant's: its error is the noise's mean, σ/√n
        assert abs(row["mae_before"] - mae_before) < 5 * sigma / math.sqrt(n)
        assert abs(row["std_before"] / sigma - 1) < rms_tolerance(n)
        assert abs(row["mae_after"] / mae_after - 1) < mae_tolerance(n)
        assert abs(row["std_after"] / sigma - 1) < rms_tolerance(n)
        assert 3 * sigma < row["max_after"] < 6 * sigma
        assert 3 * sigma < row["max_before"] - constant[k] < 6 * sigma
        # MAE compensation % = 100 (1 − MAE_after / MAE_before): with the propagated error of MAE_after
        expected_pct = 100 * (1 - mae_after / mae_before)
        pct_tolerance = 100 * mae_after / mae_before * (mae_tolerance(n) + 5 * sigma / math.sqrt(n) / mae_before)
        assert abs(row["mae_comp_pct"] - expected_pct) < pct_tolerance, (axis, row["mae_comp_pct"], expected_pct)


def test_mae_compensation_pct_definition_and_nothing_to_compensate():
    assert mae_compensation_pct(5.0, 0.1) == pytest.approx(98.0)
    assert mae_compensation_pct(2.0, 2.0) == 0.0
    assert mae_compensation_pct(1.0, 1.5) == pytest.approx(-50.0)  # a compensation that makes it worse
    assert math.isnan(mae_compensation_pct(0.0, 0.1))


def compensated_run(n=10_000, first=300, seed=11):
    """What an estimator hands the metrics: a 4 N transient decaying until it converges at ``first``,
    two presses of 3 N flagged as contact, rows it could not use (NaN), sensor noise everywhere else."""
    rng = np.random.default_rng(seed)
    values = rng.normal(0.0, SIGMA_F, (n, 3))
    k = np.arange(n)
    values[:first] += 4.0 * np.exp(-k[:first, None] / 80.0)
    contact = np.zeros(n, dtype=bool)
    for start, stop in ((2000, 2500), (7000, 7200)):
        contact[start:stop] = True
        values[start:stop] += [0.0, 1.0, 3.0]
    values[[100, 5000, 5001, n - 1]] = np.nan
    return values, contact


def test_scoring_keeps_no_contact_samples_after_convergence_only():
    n, first = 10_000, 300
    values, contact = compensated_run(n, first)
    rows = scored_rows(first, values, contact)
    # every row from 300 on, less the 500 + 200 contact rows and the three unusable rows among them (100 is earlier)
    assert rows.sum() == n - first - 500 - 200 - 3
    assert not rows[:first].any() and not rows[contact].any() and not rows[[5000, 5001, n - 1]].any()
    scored = rms_after_convergence(values, contact, first)
    assert np.all(np.abs(scored / SIGMA_F - 1) < rms_tolerance(int(rows.sum()))), scored
    # what the selection keeps out is not small: the presses alone would raise the RMS far above the noise
    with_contact = rms_after_convergence(values, None, first)
    assert with_contact[2] > 5 * SIGMA_F[2]
    # and the transient: scoring from the first sample on
    assert rms_after_convergence(values, contact, 0)[0] > 2 * SIGMA_F[0]


def test_scoring_before_any_convergence_has_no_rows():
    values, contact = compensated_run()
    assert not scored_rows(None, values, contact).any()
    assert np.isnan(rms_after_convergence(values, contact, None)).all()
    assert np.isnan(rms_after_convergence(values, contact, len(values))).all()  # converged on the last row only
    assert rms(np.zeros((0, 3))).shape == (3,) and np.isnan(rms(np.zeros((0, 3)))).all()


def test_norm_ratio_of_two_noise_levels():
    """‖RMS‖ of noise 1.5 times as large, over the same number of rows: 1.5."""
    n = 100_000
    rng = np.random.default_rng(12)
    reference = rng.normal(0.0, SIGMA_F, (n, 3))
    louder = rng.normal(0.0, 1.5 * SIGMA_F, (n, 3))
    # each RMS is within 5/√(2n) relative; their norms too, so the ratio within about twice that
    assert abs(norm_ratio(rms(louder), rms(reference)) / 1.5 - 1) < 2 * rms_tolerance(n)
    assert norm_ratio(rms(reference), rms(reference)) == 1.0


def test_the_paper_estimator_reaches_the_noise_floor_by_these_metrics():
    """rls over the paper's static model with a 3 N press: scored after its convergence and without the
    rows it refused as contact, the compensated force is the sensor noise. The fit's own error adds
    (p/n)·σ² to the mean square (6 parameters over thousands of rows): well inside the tolerance."""
    n = 6000
    block, _ = static_model_stream(n, seed=13, noise_force=0.12, noise_torque=0.01)
    block.force_S[3000:3400] += [0.0, 1.0, 3.0]
    stream = Stream(block.t_ns * 1e-9, block)
    est = run_estimator(stream, RLSEstimator())
    first = first_true(est.converged_force)
    assert first is not None and first < 1000
    rows = scored_rows(first, est.contact_force_S, est.contact)
    assert not rows[3000:3400].any()  # the press was refused as contact, so it is not scored
    scored = rms_after_convergence(est.contact_force_S, est.contact, first)
    assert np.all(np.abs(scored / 0.12 - 1) < rms_tolerance(int(rows.sum())) + 6 / (n - first)), scored
