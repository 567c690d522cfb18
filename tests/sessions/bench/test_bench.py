"""``hapticlab bench paper`` and ``hapticlab bench real``: contracts and sanity of what they measure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import static_model_stream

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.sessions.cli import main


@pytest.fixture(scope="module")
def quick(tmp_path_factory, bench_run):
    folder = tmp_path_factory.mktemp("bench")
    args = ["paper", "--quick", "--all-estimators", "--json", str(folder / "p.json"), "--plots", str(folder / "plots")]
    assert bench_run(*args) == 0
    return json.loads((folder / "p.json").read_text()), folder


def test_paper_json_has_every_key_the_issue_lists(quick):
    out, _ = quick
    for group, axes in (("force", ("fx", "fy", "fz")), ("torque", ("tx", "ty", "tz"))):
        for axis in axes:
            assert set(out["no_contact"][group][axis]) >= {
                "mae_before",
                "mae_after",
                "max_after",
                "std_after",
                "mae_comp_pct",
            }
    for method in ("batch", "rls"):
        assert set(out["bounds"][method]) == {"fx", "fy", "fz", "tx", "ty", "tz"}
    assert set(out["convergence"]) >= {"force_paper", "torque_paper", "force_truth", "torque_truth"}
    for speed in ("12", "30", "45", "72"):
        assert set(out["rotation_104g"][speed]) >= {"mae", "max_ae", "std"}
    assert set(out["estimators"]) >= {"rls", "batch"} and next(iter(out["estimators"])) == "kalman"  # the default first
    assert set(out["estimators"]["batch"]["no_contact"]["force"]) == {"fx", "fy", "fz"}
    assert set(out["estimators"]["batch"]["bounds"]) == {"batch", "batch_frozen"}


def test_paper_method_reaches_the_noise_floor(quick):
    """What the tables claim, checked: rls leaves only the sensor noise (Gamma-class, 0.12/0.12/0.06 N)."""
    out, _ = quick
    noise = np.array(out["setup"]["noise_force"])
    ratio = np.array([out["no_contact"]["force"][a]["std_after_over_noise"] for a in ("fx", "fy", "fz")])
    assert np.all(np.abs(ratio - 1.0) < 0.25)
    assert out["convergence"]["force_paper"] is not None
    assert out["indentation"]["detected_plateau_pct"] > 99.0 and out["indentation"]["false_contact_pct"] < 1.0
    # with the 104 g mass on, |contact force| stays near 1.02 N, within the noise
    for speed in ("12", "72"):
        assert abs(out["rotation_104g_low_noise"][speed]["mean"] - 1.02) < 0.02
    # the weaknesses the bench exposes: repeated first rows fake convergence ...
    assert out["repeated_rows"]["converged_force_at"] == 1 and out["repeated_rows"]["refused_pct"] > 50.0
    # ... and the fixed threshold loses hold of a drifting bias: free-space error well above the noise
    drift = out["drift_contact"]
    assert drift["rms_free_last_30s"][0] > 2 * noise[0] and drift["false_contact_last_30s_pct"] > 5.0


def test_paper_plots_are_written(quick):
    _, folder = quick
    names = sorted(p.name for p in (folder / "plots").glob("*.png"))
    assert names == [
        "drift_contact.png",
        "fig3_force_parameters.png",
        "fig4_torque_parameters.png",
        "fig5_force_compensation.png",
        "fig6_torque_compensation.png",
        "fig7_indentation.png",
        "fig8_rotation_104g.png",
        "fig9_rotation_metrics.png",
    ]
    assert all((folder / "plots" / n).stat().st_size > 10_000 for n in names)


def test_bench_real_on_a_folder(tmp_path, capsys):
    block, _ = static_model_stream(2000, seed=21, noise_force=0.1, noise_torque=0.008)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    table = np.column_stack([np.arange(2000) * 1e-3, block.force_S, block.torque_S, quat_BE])
    np.savetxt(tmp_path / "sim.csv", table, delimiter=",", header="t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz", comments="")
    assert main(["bench", "real", str(tmp_path), "--json", str(tmp_path / "r.json")]) == 0
    out = json.loads((tmp_path / "r.json").read_text())
    rls = out["sim"]["estimators"]["rls"]
    assert rls["converged_force_at"] is not None and 0.9 < rls["ratio_norm"] < 1.1
    assert 0.9 < rls["ratio_norm_second_half"] < 1.1
    assert next(iter(out["sim"]["estimators"])) == "kalman"  # the default first, estimating the sensor's noise
    kalman = out["sim"]["estimators"]["kalman"]
    assert kalman["converged_force_at"] is not None and kalman["ratio_norm_second_half"] < 1.05
    identified = out["sim"]["estimators"]["kalman convergence=identified"]  # the flag once the tool is identified
    assert kalman["converged_force_at"] <= identified["converged_force_at"]  # (equal: this stream turns at once)
    assert kalman["ratio_norm_second_half"] == identified["ratio_norm_second_half"]  # the same filter
    gamma = out["sim"]["estimators"]["kalman noise=0.12 N, convergence=covariance"]  # the old defaults beside
    assert gamma["ratio_norm_second_half"] < 1.05
    # force and torque over the last 70 % of rows, each axis against the batch fit (the simulated stream's model
    # is the batch fit's: both at the noise, within a few percent)
    for name in ("rls", "kalman", "kalman torque_start=settled"):
        r = out["sim"]["estimators"][name]
        assert np.all(np.abs(np.array(r["last_ratio_force"] + r["last_ratio_torque"]) - 1.0) < 0.1), (name, r)
    assert "sim" in capsys.readouterr().out


def test_bench_estimators_prints_every_scenario(tmp_path, capsys, bench_run):
    assert bench_run("estimators", "--json", str(tmp_path / "e.json")) == 0
    out = json.loads((tmp_path / "e.json").read_text())
    assert set(out) == {"mount", "inertia_tour", "rotation_104g", "time_lag", "gain", "payload"}
    assert out["mount"]["mount_error_deg"] <= 0.3 and 0 < out["payload"]["recognised_after_s"] < 0.5
    printed = capsys.readouterr().out
    assert "5° mount" in printed and "estimated within" in printed and "100 g payload" in printed
    assert main(["bench", "estimators", "somewhere"]) == 2
    assert "'bench estimators' takes no folder" in capsys.readouterr().err


def test_bench_options_that_do_not_belong_are_refused(capsys):
    assert main(["bench", "real", "--plots", "x"]) == 2
    assert "--plots goes with 'bench paper' or 'bench teleop'" in capsys.readouterr().err
    assert main(["bench", "teleop", "--quick"]) == 2
    assert "--quick and --all-estimators go with 'bench paper'" in capsys.readouterr().err
    assert main(["bench", "real", "/nonexistent/folder"]) == 2
    assert "no such folder; give one: hapticlab bench real DIR" in capsys.readouterr().err


def test_bench_real_keeps_going_past_a_bad_file(tmp_path):
    (tmp_path / "bad.csv").write_text("t,fx\n0,1\n")
    block, _ = static_model_stream(500, seed=22, noise_force=0.1)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    table = np.column_stack([np.arange(500) * 1e-3, block.force_S, block.torque_S, quat_BE])
    np.savetxt(tmp_path / "good.csv", table, delimiter=",", header="t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz", comments="")
    assert main(["bench", "real", str(tmp_path), "--json", str(tmp_path / "r.json")]) == 0
    out = json.loads((tmp_path / "r.json").read_text())
    assert "missing required column" in out["bad"]["error"] and "rls" in out["good"]["estimators"]


def test_metric_helpers_on_hand_made_input():
    from hapticlab.sessions.bench.paper_convergence import first_stays, truth_convergence
    from hapticlab.sessions.offline.metrics import error_stats

    before = np.array([[2.0], [-4.0], [6.0]])
    after = np.array([[0.1], [-0.3], [0.2]])
    stats = error_stats(before, after, ("fx",))["fx"]
    assert stats["mae_before"] == 4.0 and stats["max_before"] == 6.0
    assert np.isclose(stats["mae_after"], 0.2) and np.isclose(stats["max_after"], 0.3)
    assert np.isclose(stats["std_after"], np.std([0.1, -0.3, 0.2]))
    assert np.isclose(stats["mae_comp_pct"], 95.0)
    index = np.array([0, 1, 2, 3, 4, 5])
    assert first_stays(np.array([0, 1, 1, 0, 1, 1], bool), index) == 4  # left the band at 3
    assert first_stays(np.array([1, 1, 1, 1, 1, 0], bool), index) is None
    truth = {"gravity_force_B": np.array([0.0, 0.0, -2.0]), "bias_force_S": np.zeros(3), "bias_torque_S": np.zeros(3)}
    g = np.tile([0.0, 0.0, -2.0], (6, 1))
    g[2, 2] = -2.1  # 5 % off once
    trace = {"gravity_force_B": g, "bias_force_S": np.zeros((6, 3)), "bias_torque_S": np.full((6, 3), 0.001)}
    trace["bias_torque_S"][:4] = 0.01
    assert truth_convergence(index, trace, truth) == (3, 4)


def test_bench_real_exposes_the_repeated_first_samples(real_data, tmp_path, bench_run):
    assert bench_run("real", str(real_data), "--json", str(tmp_path / "r.json")) == 0
    out = json.loads((tmp_path / "r.json").read_text())
    # the LWR4 logs start with identical rows: ‖Δx‖ < 1e-3 at the second sample
    assert out["lwr4_2013_06_13"]["estimators"]["rls"]["converged_force_at"] == 1
    assert out["axia80_ur_100poses"]["estimators"]["rls"]["converged_force_at"] is None
    # kalman's lone outliers on a contact-free log: held out, counted beside the contact rows (rls has none)
    kalman, rls = (out["lwr4_2014_06_24"]["estimators"][name] for name in ("kalman", "rls"))
    assert (kalman["contact_rows"], kalman["held_out_rows"]) == (0, 5) and "held_out_rows" not in rls
    # the torque: kalman's stage starts with the first sample, within the batch fit's on the last 70 % of rows;
    # started once the force stage has settled (sample 1230 of 2500 here, its former default), the raw torque
    # stands in for the estimate until then, 45× the batch fit's
    settled = out["lwr4_2014_06_24"]["estimators"]["kalman torque_start=settled"]
    assert max(settled["last_ratio_torque"]) > 10 and max(kalman["last_ratio_torque"]) < 1.0
    assert settled["last_ratio_force"] == kalman["last_ratio_force"]  # the force stage is the same
    assert kalman["converged_torque_at"] >= kalman["converged_force_at"]  # its flag still waits for the force's


def test_the_teleoperation_stage_table_times_a_press_into_the_tissue():
    """``bench loop``'s teleoperation table: the preset's own estimator and shadow, a master that presses
    once the tour is over (the tool goes into the tissue: contact samples), and the teleoperation step and
    the shadows timed in their own rows."""
    from hapticlab.sessions.bench.loop import STAGES, stage_table

    run = stage_table(1000.0, 6.0, estimator=None, preset="teleop-emulated")
    assert (run["estimator"], run["shadows"], run["ticks"]) == ("kalman", ["rls"], 6000)
    assert run["contact_samples"] > 100
    assert set(run["us_per_tick"]) == set(STAGES)
    for stage in ("teleoperation", "shadow estimators", "sensor read", "kinematics read"):
        assert run["us_per_tick"][stage] > 0, stage
    demo = stage_table(1000.0, 0.5)  # the demo with `rls` alone: no teleoperation, no shadow
    assert demo["us_per_tick"]["teleoperation"] == demo["us_per_tick"]["shadow estimators"] == 0
    # the session's start and end (the writer process's spawn, the file's end) are apart from the ticks
    assert demo["start_end_ms"] > 0 and demo["x_real_time_session"] < demo["x_real_time"]
    # without the stopwatches only the ticks are timed: the whole tick is the "loop body"
    bare = stage_table(1000.0, 0.5, stopwatches=False)
    assert bare["us_per_tick"]["loop body"] > 0 and bare["x_real_time"] > 0
    assert all(bare["us_per_tick"][stage] == 0 for stage in STAGES if stage != "loop body")


def test_the_paper_s_flag_converges_sooner_on_a_faster_tour():
    """bench paper's conditions: under Algorithm 1's flag the force stage converges sooner the faster the tour
    shows new orientations (at the set-up's noise), and the set-up's own condition is the bench's run."""
    from hapticlab.core.host.registry import Registry
    from hapticlab.sessions.bench.paper import estimator_factory
    from hapticlab.sessions.bench.paper_convergence import PACES_S, closest_condition, convergence_conditions
    from hapticlab.sessions.bench.paper_setup import PaperSetup

    setup = PaperSetup()
    rows = convergence_conditions(setup, estimator_factory(Registry(), "rls", setup))
    full = {r["pace_s"]: r for r in rows if r["noise_scale"] == 1.0}
    assert [full[p]["force"] for p in PACES_S] == sorted((full[p]["force"] for p in PACES_S), reverse=True)
    assert full[3.0]["force"] > 2 * full[0.3]["force"]
    near = closest_condition(rows, 242, 238)
    assert near is not None and abs(near["force"] - 242) + abs(near["torque_after_force"] - 238) < 150
