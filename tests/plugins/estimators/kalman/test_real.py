"""``kalman`` on the real recordings (skipped when ``shared/data/real`` is absent): the estimator's
target (online RMS ≤ 1.05× the offline batch fit), and the effects the discrepancy workflow names, used
online, shrinking the gap in the estimator that drives the haptics too.

Scored over each file's second half, the same rows for every estimator whatever its own convergence
flag says (``hapticlab bench real``'s "2nd half" column).
"""

from __future__ import annotations

import pytest

from hapticlab.core.estimation.batch import batch_fit
from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.sessions.bench import real as realbench
from hapticlab.sessions.bench.simulation import feed
from hapticlab.sessions.discrepancy.workflow import discrepancy
from hapticlab.sessions.offline.compensate import run_estimator
from hapticlab.sessions.recording import load_stream

AUTO = {"noise_force": "auto", "noise_torque": "auto"}


def kalman_ratio(path, options) -> float:
    """‖online RMS‖ / ‖batch-fit RMS‖ over the file's second half."""
    stream = load_stream(path)
    s = stream.samples
    residual = batch_fit(s.force_S, s.torque_S, s.R_EB)["residual_force_S"]
    est = run_estimator(stream, KalmanEstimator(**AUTO, **options))
    return realbench.second_half_ratio(est.contact_force_S, residual)


@pytest.fixture(scope="module")
def named(real_data):
    """The estimator options ``hapticlab discrepancy`` suggests for each real file."""
    return {path.stem: discrepancy(path)["estimator_options"] for path in sorted(real_data.glob("*.csv"))}


def test_the_named_effects_bring_every_file_under_the_batch_fit(real_data, named):
    ratios = {}
    for path in sorted(real_data.glob("*.csv")):
        ratios[path.stem] = (kalman_ratio(path, {}), kalman_ratio(path, named[path.stem]))
    print(
        "\nkalman noise=auto, second half, ‖online‖/‖batch‖ (alone, with the named effects): "
        + "; ".join(f"{k} {a:.2f} → {b:.2f} {named[k]['effects']}" for k, (a, b) in ratios.items())
    )
    assert all(b <= 1.05 for _, b in ratios.values()), ratios
    # where something was named, it helps online too
    for stem, (alone, with_effects) in ratios.items():
        if named[stem]["effects"]:
            assert with_effects < alone, stem


def test_the_axia80_calibration_error_carries_over_to_the_other_recording(real_data, named):
    """Out of sample: the force sensor's calibration error found on the 10 Hz log, used on the 100 poses."""
    log = named["axia80_ur_log_10hz"]
    assert "gain_crosstalk" in log["effects"]
    gain = {"gain_force_S": log["gain_force_S"], "gain_torque_S": log["gain_torque_S"]}
    poses = real_data / "axia80_ur_100poses.csv"
    alone = kalman_ratio(poses, {})
    carried = kalman_ratio(poses, dict(gain, mount_rotation=True))
    print(
        f"\naxia80_ur_100poses, second half: {alone:.2f} alone, {carried:.2f} with the 10 Hz log's "
        f"calibration error and an online mount estimate"
    )
    assert alone > 1.05 and carried <= 1.05


def test_identified_convergence_comes_as_soon_as_the_motion_allows_on_every_file(real_data):
    """convergence = "identified" with auto noise: the force stage converges on every real file, never before
    the first row at which the motion identifies gravity to half the noise at all (a constant-bias fit with
    the noise known: no honest rule can be earlier) and at most 2 % of the file's rows, or 5 rows, after it.
    (The noise is estimated sample by sample, and each row's information counts with the noise as estimated
    then: on the 100-row file the estimate is still falling from its 0.5 N start at row 47, so the flag
    comes 5 rows after the limit.)"""
    from hapticlab.sessions.bench.identifiability import first_below, gravity_std_over_rows

    wide_P = []
    for path in sorted(real_data.glob("*.csv")):
        stream = load_stream(path)
        limit = first_below(gravity_std_over_rows(stream.samples.R_EB), 0.5)
        est = KalmanEstimator(**AUTO, convergence="identified")
        run_estimator(stream, est)
        assert limit is not None and est.first_converged_force is not None, path.stem
        assert 0 <= est.first_converged_force - limit <= max(5, 0.02 * len(stream.t_s)), (
            path.stem,
            est.first_converged_force,
            limit,
        )
        # the std the haptic gate reads agrees with the flag, where the filter's own P would hold it off
        bound = est._bounds()[0]
        if est.converged_force:
            assert est.force_parameter_std().max() < bound, path.stem
            wide_P.append(float(abs(est.force.P.diagonal()[:6]).max() ** 0.5) > bound)
    assert any(wide_P)  # (lwr4_2014_06_24: the filter's P of gravity 0.067 N against a 0.058 N bound)


def test_the_defaults_converge_within_the_first_quarter_and_match_the_batch_fit(real_data):
    """The defaults (convergence = "pose") on every real file, scored as ``hapticlab bench real`` scores them:
    the force flag is up within the first quarter of the file, and over every row from there on the online
    ‖RMS‖ is at most 1.05 times the batch fit's over the same rows. The rule changes the flags only: the
    contact wrench and the refusals are those of convergence = "identified" to the bit (the torque stage and
    the noise estimate wait for the weight to be identified under both), and its flag is up wherever that
    rule's is."""
    import numpy as np

    from hapticlab.core.types import first_true
    from hapticlab.sessions.offline.metrics import norm_ratio, rms, scored_rows

    for path in sorted(real_data.glob("*.csv")):
        stream = load_stream(path)
        s = stream.samples
        residual = batch_fit(s.force_S, s.torque_S, s.R_EB)["residual_force_S"]
        pose = run_estimator(stream, KalmanEstimator())
        identified = run_estimator(stream, KalmanEstimator(convergence="identified"))
        first = first_true(pose.converged_force)
        assert first is not None and first <= len(s) // 4, (path.stem, first)
        rows = scored_rows(first, pose.contact_force_S)
        ratio = norm_ratio(rms(pose.contact_force_S[rows]), rms(residual[rows]))
        assert ratio <= 1.05, (path.stem, ratio)
        for key in ("contact_force_S", "contact_torque_S", "contact"):
            assert np.array_equal(getattr(pose, key), getattr(identified, key), equal_nan=True), (path.stem, key)
        assert not (identified.converged_force & ~pose.converged_force).any(), path.stem


LONG = ("axia80_ur_log_10hz", "lwr4_2013_06_13", "lwr4_2014_06_24", "lwr4_2014_root")
"""The real files long enough to split in two halves that each identify the tool."""


def test_a_warm_start_picks_up_a_real_file_where_its_first_half_left_it(real_data, tmp_path):
    """Defaults on each long file's first half, the state saved as a file; a new estimator warm-started from it
    on the second half converges (force stage) on its first row, and compensates exactly as the estimator
    that ran on (the same rows both call contact-free, to 0.1 %). Before the identified rule's information
    went into the state, the warm start converged 406-633 rows into the lwr4 halves (seeded from P alone,
    it began from what the bias's random walk had not yet forgotten)."""
    import json

    import numpy as np

    for stem in LONG:
        s = load_stream(real_data / f"{stem}.csv").samples
        half = len(s) // 2
        cold = KalmanEstimator()
        feed(cold, s.subset(slice(0, half)), chunk=64)
        assert cold.converged_force, stem
        path = tmp_path / f"{stem}.json"
        path.write_text(json.dumps(cold.state()))
        warm = KalmanEstimator(warm_start=str(path))
        second = s.subset(slice(half, len(s)))
        (out_warm, _), (out_cold, _) = feed(warm, second, chunk=64), feed(cold, second, chunk=64)
        assert warm.first_converged_force == 0, (stem, warm.first_converged_force)
        free = ~(out_warm.contact | out_cold.contact)
        rms = [np.sqrt(np.nanmean(out.contact_force_S[free] ** 2)) for out in (out_warm, out_cold)]
        assert abs(rms[0] / rms[1] - 1) < 1e-3, (stem, rms)


def test_a_mass_hung_on_the_tool_in_a_real_log_is_a_payload_change(real_data):
    """The axia80 10 Hz log with 100 g hung on its tool at 60 % of the file (the weight along the batch fit's
    gravity, acting at its centre of mass): the defaults name one payload change, after the hang, and the
    weight they identify by the end grew by the 0.98 N hung, within 0.05 N per axis. (On the lwr4 files,
    whose t counts rows, the step is taken up by the bias's random walk over the 1 "s" between rows: no
    payload change is named there; see the note in docs/estimators.md.)"""
    from dataclasses import replace

    import numpy as np

    s = load_stream(real_data / "axia80_ur_log_10hz.csv").samples
    n, hang = len(s), int(0.6 * len(s))
    fit = batch_fit(s.force_S, s.torque_S, s.R_EB)
    weight_B = 0.1 * 9.81 * fit["gravity_force_B"] / np.linalg.norm(fit["gravity_force_B"])
    added_S = np.zeros((n, 3))
    added_S[hang:] = s.R_EB[hang:] @ weight_B
    heavier = replace(s, force_S=s.force_S + added_S, torque_S=s.torque_S + np.cross(fit["cog_S"], added_S))
    plain, est = KalmanEstimator(), KalmanEstimator()
    feed(plain, s, chunk=64)
    feed(est, heavier, chunk=64)
    changes = [e for e in est.drain_events() if e.kind == "payload_change"]
    assert len(changes) == 1 and changes[0].t_ns > s.t_ns[hang]
    grew = np.array(est.params()["gravity_force_B"]) - np.array(plain.params()["gravity_force_B"])
    assert np.abs(grew - weight_B).max() < 0.05, (grew, weight_B)


def test_lwr4_2013_06_13s_late_torque_refusal_is_reidentified(real_data):
    """A contact-free log whose last ~540 rows the torque stage refuses (the force stage accepting from row ~4930
    on): the torque bias re-opened once, and the rows refused down from 9.9 % (11.3 % before the torque stage
    regressed on the measured force) to 2.0 %, what the force stage refuses while its own estimate catches up;
    both with the tilt walk off, as before 2026-11-28. With the
    tilt walk learnt (``bias_force_tilt_rw = "auto"``, the default since) the torque bias walks with the tilt
    too (5/65 of the force's), and nothing is refused."""
    stream = load_stream(real_data / "lwr4_2013_06_13.csv")
    est = KalmanEstimator(bias_force_tilt_rw=0.0)
    with_rule = run_estimator(stream, est)
    without = run_estimator(stream, KalmanEstimator(torque_reopen_s=0.0, bias_force_tilt_rw=0.0))
    reopened = [e for e in est.drain_events() if e.kind == "torque_bias_reopened"]
    assert len(reopened) == 1
    assert without.contact.mean() > 0.09 and with_rule.contact.mean() < 0.021
    assert with_rule.contact_force_S.tolist() == without.contact_force_S.tolist()
    learnt = KalmanEstimator()
    assert learnt.tilt_walk_auto and not run_estimator(stream, learnt).contact.any()
    assert not [e for e in learnt.drain_events() if e.kind == "torque_bias_reopened"]


def test_the_lwr4_logs_lone_outliers_are_held_out_not_called_contacts(real_data):
    """The 2014 LWR4 logs are contact-free, and their noise is heavier-tailed than Gaussian: every sample to
    which contact_after = 1 gives the contact flag there is a lone one (or, once on lwr4_2014_root, a pair),
    at a Mahalanobis distance of 4.6–5.5. With the default (2) no row of lwr4_2014_06_24 is a contact and one
    of lwr4_2014_root is (the pair's second); the lone ones are counted held out, and the contact wrench is
    the same to the bit."""
    import numpy as np

    for stem, every_rows, contact_rows, held_rows in (("lwr4_2014_06_24", 5, 0, 5), ("lwr4_2014_root", 7, 1, 5)):
        stream = load_stream(real_data / f"{stem}.csv")
        every_est, default_est = KalmanEstimator(contact_after=1), KalmanEstimator()
        every, default = run_estimator(stream, every_est), run_estimator(stream, default_est)
        assert int(every.contact.sum()) == every_rows, stem
        assert int(default.contact.sum()) == contact_rows, stem
        assert default_est.held_out_samples == held_rows, stem
        assert np.array_equal(default.contact_force_S, every.contact_force_S), stem


def test_the_compiled_effects_are_the_reference_on_every_real_file(real_data, named):
    """The effects the discrepancy workflow names on each real file (warm_up's bias rates, the 10 Hz log's
    sensor lag and calibration error) and an online mount estimate, compiled (the default kernel) and as the
    numpy reference: the same contact and convergence flags, the contact force within 1e-9 N (measured
    4e-11), on these 1–10 Hz logs, whose rows the rate states predict over up to a second."""
    import numpy as np

    for path in sorted(real_data.glob("*.csv")):
        stream = load_stream(path)
        for options in (named[path.stem], {"mount_rotation": True}):
            ref = run_estimator(stream, KalmanEstimator(kernel="numpy", **options))
            out = run_estimator(stream, KalmanEstimator(**options))
            for key in ("contact", "converged_force", "converged_torque"):
                assert np.array_equal(getattr(ref, key), getattr(out, key)), (path.stem, options, key)
            assert np.abs(ref.contact_force_S - out.contact_force_S).max() < 1e-9, (path.stem, options)


def test_the_tilt_walk_follows_lwr4_2013_06_13s_fast_turn(real_data):
    """lwr4_2013_06_13 turns gravity's direction 74° in the 100 rows from 4859; the base model's error there
    changes by 0.5 N, faster than the bias's walk over time follows, and with the tilt walk off (the defaults
    before 2026-11-28) those rows are refused as a contact. With the walk over the tilt, given (0.1 N/√rad, half
    the smallest rate, ~0.2 N/√rad, at which the real files' batch residuals vary with the tilt) or learnt from
    the file as it runs ("auto", the default since), no row is, and the online RMS over the second half comes
    further under the batch fit's.
    The learnt walk is of the file's own scale, learnt from the rows before the turn."""
    import numpy as np

    stream = load_stream(real_data / "lwr4_2013_06_13.csv")
    plain = run_estimator(stream, KalmanEstimator(bias_force_tilt_rw=0.0))
    before_turn = KalmanEstimator(bias_force_tilt_rw="auto")  # what it learns from the rows before the turn
    feed(before_turn, stream.samples.subset(slice(0, 4850)), chunk=64)
    tilted = run_estimator(stream, KalmanEstimator(bias_force_tilt_rw=0.1))
    auto = KalmanEstimator()
    learnt = run_estimator(stream, auto)
    refused = np.flatnonzero(plain.contact)
    assert len(refused) >= 50 and 4800 <= refused.min() and refused.max() <= 5000  # the turn, nowhere else
    assert not tilted.contact.any() and not learnt.contact.any()
    s = stream.samples
    residual = batch_fit(s.force_S, s.torque_S, s.R_EB)["residual_force_S"]
    ratios = [realbench.second_half_ratio(out.contact_force_S, residual) for out in (plain, tilted, learnt)]
    print(
        f"\nlwr4_2013_06_13, 2nd-half RMS / batch fit: walk off {ratios[0]:.3f}, 0.1 N/√rad {ratios[1]:.3f}, "
        f"learnt {ratios[2]:.3f} ({auto.params()['bias_force_tilt_rw'][0]:.3f} N/√rad at the end)"
    )
    assert ratios[1] < ratios[0] < 1.0 and ratios[2] < ratios[0], ratios
    assert 0.1 <= before_turn.params()["bias_force_tilt_rw"][0] <= 0.45
