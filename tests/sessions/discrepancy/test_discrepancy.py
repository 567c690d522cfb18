"""``hapticlab discrepancy``: recordings from the simulated world with known hidden effects.

Each scenario hides exactly the effects it names (a "lively" 30 s tour at
250 Hz; the tool's inertia only where it is the hidden effect, the paper's
static model otherwise), with realistic sizes: a 2.7° mount rotation, a
0.5 N/min drift, an 8 ms kinematics lag, 1–2 % symmetric calibration errors,
the inertia of a 0.35 kg instrument on 1 s moves. The workflow must name
exactly those (nothing on the clean recording, for several seeds) and bring the
force RMS to within 10 % of the sensor's noise (0.12 N).
"""

from __future__ import annotations

import json
import tomllib
import types

import numpy as np
import pytest

from hapticlab.core import hookimpl
from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.core.host.registry import Registry, make_plugin_manager
from hapticlab.core.sensor_model import Effect, ModelState
from hapticlab.plugins.simworld import Indentation, RandomTour, RobotParams, SensorParams, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.plugins.simworld.motion import StaticPoses
from hapticlab.sessions.cli import main
from hapticlab.sessions.discrepancy.heldout import sign_test_p, wins_needed
from hapticlab.sessions.discrepancy.identify import Identification
from hapticlab.sessions.discrepancy.report import json_ready, toml_snippet
from hapticlab.sessions.discrepancy.settings import Settings
from hapticlab.sessions.discrepancy.workflow import discrepancy
from hapticlab.sessions.recording import load_stream

NOISE = 0.12  # N, the simulated sensor's default force noise per axis
MOUNT = np.deg2rad([2.0, -1.5, 1.0])  # 2.7°
DRIFT = np.array([0.5, -0.3, 0.4]) / 60  # N/s
LAG = 0.008  # s, kinematics late
GF = np.array([[0.02, 0.01, -0.005], [0.01, -0.015, 0.008], [-0.005, 0.008, -0.005]])
GT = np.array([[-0.01, 0.004, 0.0], [0.004, 0.02, -0.01], [0.0, -0.01, -0.01]])

SCENARIOS = {
    "none": {},
    "mount_rotation": {"sensor": {"mount_rotation_SE": MOUNT}},
    "bias_drift": {"sensor": {"drift_force_S": DRIFT, "drift_torque_S": np.array([0.02, -0.01, 0.015]) / 60}},
    "inertia": {"inertia": True},
    "time_lag": {"robot": {"kinematics_lag_s": LAG}},
    "gain_crosstalk": {"sensor": {"gain_force_S": GF, "gain_torque_S": GT}},
    "mount_rotation+bias_drift": {"sensor": {"mount_rotation_SE": MOUNT, "drift_force_S": DRIFT}},
    "time_lag+gain_crosstalk": {"sensor": {"gain_force_S": GF}, "robot": {"kinematics_lag_s": -0.006}},
}


def world_for(scenario: str, seed: int, contacts=()) -> SimWorld:
    hidden = SCENARIOS[scenario]
    return SimWorld(
        sensor=SensorParams(**hidden.get("sensor", {})),
        robot=RobotParams(**hidden.get("robot", {})),
        motion=RandomTour(seed=seed, segment_s=1.0, max_translation=0.05),
        contacts=contacts,
        seed=seed,
        inertia=hidden.get("inertia", False),
    )


def run(tmp_path, scenario: str, seed: int = 1, duration: float = 30.0, rate: float = 250.0, **kwargs):
    path = tmp_path / f"{scenario}_{seed}.csv"
    world = world_for(scenario, seed, kwargs.pop("contacts", ()))
    write_csv(world, path, duration, rate)
    return discrepancy(path, **kwargs), world


def expected(scenario: str) -> set[str]:
    return set() if scenario == "none" else set(scenario.split("+"))


@pytest.mark.parametrize("scenario", [s for s in SCENARIOS if s != "none"])
def test_names_exactly_the_hidden_effects_and_closes_the_gap(tmp_path, scenario):
    result, _ = run(tmp_path, scenario)
    assert set(result["effects"]) == expected(scenario), result["rounds"]
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.10 * NOISE), result["final"]
    assert np.all(np.array(result["baseline"]["rms_force_S"]) >= np.array(result["final"]["rms_force_S"]))
    assert result["gated"] == 0
    assert result["leftover"]["axes"] == []  # nothing left on any axis, against its own noise


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_clean_recording_names_nothing(tmp_path, seed):
    result, _ = run(tmp_path, "none", seed=seed)
    assert result["effects"] == [] and result["steps"] == []
    assert all(not e["significant"] for e in result["rounds"][0])
    # every built-in was tested, and the workflow's own refinements beside time_lag and payload_change
    tested = sorted(e["effect"] for e in result["rounds"][0])
    assert tested == sorted([*Registry().names("effect"), "clock_skew", "payload_ramp"])
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.10 * NOISE)
    assert result["estimator_options"] == {"effects": []}
    assert result["leftover"]["axes"] == [] and not result["warnings"]["leftover"]


@pytest.mark.parametrize("scenario", ["mount_rotation", "time_lag", "gain_crosstalk", "bias_drift", "inertia"])
def test_other_seeds_name_the_same(tmp_path, scenario):
    for seed in (6, 7, 8):
        result, _ = run(tmp_path, scenario, seed=seed)
        assert set(result["effects"]) == expected(scenario), (seed, result["rounds"])
        assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.05 * NOISE), (seed, result["final"])


def test_identified_parameters_are_the_hidden_ones(tmp_path):
    result, _ = run(tmp_path, "mount_rotation+bias_drift", seed=2)
    params = result["final"]["params"]
    assert np.degrees(np.linalg.norm(np.array(params["mount_rotation"]["mount_rotation_SE"]) - MOUNT)) < 0.1
    np.testing.assert_allclose(params["bias_drift"]["bias_force_rate_S"], DRIFT, atol=0.05 / 60)
    lag, _ = run(tmp_path, "time_lag", seed=2)
    kalman = Registry().create("estimator", "kalman", lag["estimator_options"], where="estimator")
    assert kalman.time_lag_s == pytest.approx(LAG, abs=0.001)
    assert lag["final"]["params"]["time_lag"]["time_lag_s"] == pytest.approx(LAG, abs=0.001)
    assert lag["estimator_options"] == {
        "effects": ["time_lag"],
        "time_lag_s": lag["final"]["params"]["time_lag"]["time_lag_s"],
    }
    gain, _ = run(tmp_path, "gain_crosstalk", seed=2)
    np.testing.assert_allclose(gain["estimator_options"]["gain_force_S"], GF, atol=0.003)
    Registry().create("estimator", "kalman", gain["estimator_options"], where="estimator")
    inertia, world = run(tmp_path, "inertia", seed=2)
    named = inertia["final"]["params"]["inertia"]
    assert named["mass_scale"] == pytest.approx(1.0, abs=0.05)
    # Ixx, Iyy (1.5e-3 kg·m²) to 10 %; Izz (6e-5 kg·m², a 1 cm thin instrument) to 3e-5, its size
    np.testing.assert_allclose(np.diag(named["inertia_S"])[:2], np.diag(world.tool.inertia_S)[:2], rtol=0.1)
    assert named["inertia_S"][2][2] == pytest.approx(world.tool.inertia_S[2, 2], abs=3e-5)
    np.testing.assert_allclose(named["sensor_offset_S"], 0.0, atol=0.005)  # the world's sensor is at the flange


def test_contact_is_gated_and_does_not_fake_an_effect(tmp_path):
    contacts = [Indentation(start=s, duration=1.5, peak_force=2.5) for s in (5.0, 14.0, 23.0)]
    result, world = run(tmp_path, "mount_rotation", seed=3, contacts=contacts)
    assert result["effects"] == ["mount_rotation"]
    t = np.arange(0, 30, 1 / 250)
    in_contact = world.wrench(t, noise=False)["contact"]
    assert result["gated"] >= 0.9 * in_contact.sum()  # the contact (and a margin either side) set aside
    kept = result["_kept"]
    pressed = np.linalg.norm(world.wrench(t, noise=False)["contact_force_S"], axis=1) > 0.5  # N
    assert not np.any(kept & pressed)
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.10 * NOISE)


def test_an_mcap_session_recording(tmp_path, long_session):
    from hapticlab.sessions.config import apply_overrides, load_config
    from hapticlab.sessions.live import build_session

    config, _ = load_config("demo")
    config = apply_overrides(
        config,
        [
            "session.realtime=false",
            "session.duration=12.0",
            "world.inertia=false",
            "world.sensor.mount_rotation=[0.035, -0.026, 0.017]",
        ],
    )
    path = long_session(build_session(config), out=tmp_path / "s.mcap").path
    result = discrepancy(path)
    assert result["effects"] == ["mount_rotation"] and result["time_base"] == "seconds"
    assert result["gated"] > 0  # the demo's indentations
    np.testing.assert_allclose(
        result["final"]["params"]["mount_rotation"]["mount_rotation_SE"], [0.035, -0.026, 0.017], atol=0.002
    )


class CableSway(Effect):
    """A third party's effect: a force swinging with the flange's roll (a cable), 2 parameters."""

    stage = "bias"
    labels = ("cos_N", "sin_N")
    steps = (1e-4, 1e-4)

    def apply(self, state: ModelState, params):
        roll = np.arctan2(state.motion.R_EB[:, 0, 1], state.motion.R_EB[:, 0, 0])
        force = np.zeros_like(state.force_S)
        force[:, 0] = params[0] * np.cos(2 * roll) + params[1] * np.sin(2 * roll)
        return state.replace(force_S=state.force_S + force)


def test_a_third_party_effect_is_tested_and_named(tmp_path):
    plugin = types.ModuleType("cable_plugin")
    plugin.register_effects = hookimpl(lambda register: register("cable_sway", CableSway))
    pm = make_plugin_manager(load_entry_points=False)
    pm.register(plugin, name="cable_plugin")
    registry = Registry(pm)
    path = tmp_path / "cable.csv"
    write_csv(world_for("none", 4), path, 30.0, 250.0)
    rows = np.loadtxt(path, delimiter=",", skiprows=1)
    from hapticlab.core.frames import matrix_from_quat_wxyz

    R_EB = matrix_from_quat_wxyz(rows[:, 7:11]).transpose(0, 2, 1)
    roll = np.arctan2(R_EB[:, 0, 1], R_EB[:, 0, 0])
    rows[:, 1] += 0.1 * np.cos(2 * roll)  # hidden: 0.1 N of cable sway
    np.savetxt(path, rows, delimiter=",", header="t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz,px,py,pz", comments="")
    result = discrepancy(path, registry=registry)
    assert result["effects"] == ["cable_sway"]
    assert result["final"]["params"]["cable_sway"]["cos_N"] == pytest.approx(0.1, abs=0.01)
    assert "cable_sway" not in result["estimator_options"]


def test_command_line_json_plots_and_toml(tmp_path, capsys):
    path = tmp_path / "rec.csv"
    write_csv(world_for("mount_rotation+bias_drift", 5), path, 20.0, 250.0)
    assert main(["discrepancy", str(path), "--json", str(tmp_path / "d.json"), "--plots", str(tmp_path / "p")]) == 0
    captured = capsys.readouterr()
    data = json.loads((tmp_path / "d.json").read_text())
    # the DESIGN.md contract
    assert {"baseline", "steps", "final", "effects", "estimator_options"} <= set(data)
    assert set(data["baseline"]) == {"rms_force_S", "rms_torque_S"}
    assert {"rms_force_S", "rms_torque_S"} <= set(data["final"])
    for step in data["steps"]:
        assert {
            "effect",
            "params",
            "score",
            "rms_force_before",
            "rms_force_after",
            "rms_torque_before",
            "rms_torque_after",
        } <= set(step)
        assert len(step["rms_force_before"]) == 3 and len(step["rms_torque_after"]) == 3
    assert data["effects"] == [s["effect"] for s in data["steps"]]
    assert set(data["effects"]) == {"mount_rotation", "bias_drift"}
    assert data["steps"][0]["rms_force_after"] == data["steps"][1]["rms_force_before"]
    # the TOML snippet at the end of the output is a valid [estimator] table with those options
    snippet = captured.out[captured.out.index("[estimator]") :]
    estimator = tomllib.loads(snippet)["estimator"]
    assert estimator["name"] == "kalman" and estimator["effects"] == data["effects"]
    np.testing.assert_allclose(
        estimator["mount_rotation_SE"], data["estimator_options"]["mount_rotation_SE"], rtol=1e-5
    )
    # ... which the kalman estimator takes as it is (the effects online)
    kalman = Registry().create(
        "estimator", "kalman", {k: v for k, v in estimator.items() if k != "name"}, where="estimator"
    )
    assert set(kalman.effects) >= set(data["effects"])
    assert "steps: RMS per axis" in captured.out and "named:" in captured.out
    written = sorted(p.name for p in (tmp_path / "p").iterdir())
    assert written == [
        "00_baseline.png",
        "01_after_bias_drift.png",
        "02_after_mount_rotation.png",
        "steps.png",
    ] or written == ["00_baseline.png", "01_after_mount_rotation.png", "02_after_bias_drift.png", "steps.png"]


def test_toml_snippet_round_trips():
    options = {
        "effects": ["time_lag", "gain_crosstalk"],
        "time_lag_s": -0.0123456789,
        "gain_force_S": GF.tolist(),
        "gain_torque_S": GT.tolist(),
    }
    table = tomllib.loads(toml_snippet(options))["estimator"]
    assert table["effects"] == options["effects"] and table["time_lag_s"] == pytest.approx(-0.0123457, rel=1e-6)
    np.testing.assert_allclose(table["gain_force_S"], GF, atol=1e-9)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["discrepancy", "missing.csv"], "missing.csv: no such file"),
        (["discrepancy", "{bad}"], "bad.csv line 3, column 'fz': 'x' is not a finite number"),
        (["discrepancy", "{short}"], "short.csv: 2 rows; the workflow needs at least 20"),
        (["discrepancy", "{good}", "--effects", "mount_rotation,wobble"], "--effects: unknown effect 'wobble'"),
        (["discrepancy", "{good}", "--set", "bias_drift.ordr=2"], "effects.bias_drift.ordr: unknown option"),
        (["discrepancy", "{good}", "--set", "bias_drift.order=7"], "effects.bias_drift.order: must be 1, 2 or 3"),
        (["discrepancy", "{good}", "--set", "order=2"], "expected EFFECT.OPTION=VALUE"),
        (["discrepancy", "{good}", "--json", "/no/such/folder/out.json"], "folder /no/such/folder does not exist"),
        (["discrepancy", "{good}", "--json", "{tmp}"], "--json {tmp}: is a folder"),
        (["discrepancy", "{good}", "--plots", "{good}"], "--plots {good}: exists and is not a folder"),
        (["discrepancy", "{good}", "--plots", "{good}/figs"], "is not a folder"),
    ],
)
def test_bad_input_is_one_line(tmp_path, capsys, argv, message):
    (tmp_path / "bad.csv").write_text("t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n0,1,2,3,4,5,6,1,0,0,0\n1,1,2,x,4,5,6,1,0,0,0\n")
    (tmp_path / "short.csv").write_text(
        "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n0,1,2,3,4,5,6,1,0,0,0\n1,1,2,3,4,5,6,1,0,0,0\n"
    )
    write_csv(world_for("none", 1), tmp_path / "good.csv", 2.0, 50.0)
    names = {
        "bad": tmp_path / "bad.csv",
        "short": tmp_path / "short.csv",
        "good": tmp_path / "good.csv",
        "tmp": tmp_path,
    }
    argv = [a.format(**names) if a.startswith("{") else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    message = message.format(**names)
    assert err.startswith("hapticlab discrepancy: error: ") and message in err and "\n" not in err, err
    assert "Traceback" not in err


def test_the_json_is_written_before_the_plots_and_a_plot_error_is_one_line(tmp_path, capsys, monkeypatch):
    import hapticlab.sessions.discrepancy.plots as plots

    def broken(result, folder, force=False):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plots, "write_plots", broken)
    path = tmp_path / "rec.csv"
    write_csv(world_for("none", 1), path, 4.0, 100.0)
    code = main(["discrepancy", str(path), "--json", str(tmp_path / "d.json"), "--plots", str(tmp_path / "p")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("hapticlab discrepancy: error: --plots") and "No space left on device" in err
    assert json.loads((tmp_path / "d.json").read_text())["effects"] == []


def test_effect_options_and_a_restricted_candidate_list(tmp_path):
    path = tmp_path / "drift.csv"
    write_csv(world_for("bias_drift", 1), path, 30.0, 250.0)
    result = discrepancy(
        path, Settings(effects=["bias_drift", "mount_rotation"], effect_options={"bias_drift": {"order": 2}})
    )
    assert [e["effect"] for e in result["rounds"][0]] == ["bias_drift", "mount_rotation"]
    assert result["effects"] == ["bias_drift"]
    assert "bias_force_d2_S" in result["final"]["params"]["bias_drift"]


def test_every_real_recording(real_data):
    """What the workflow names on the real files, and that adding effects never loses to the batch fit."""
    results = {}
    for path in sorted(real_data.glob("*.csv")):
        result = json_ready(discrepancy(path))
        results[path.stem] = result
        final, batch = np.array(result["final"]["rms_force_S"]), np.array(result["batch_fit"]["rms_force_S"])
        if result["effects"]:
            # every named step passed the rule, and together they take at least 10 % off the batch fit's RMS
            for step in result["steps"]:
                if step["action"] != "named" or step["effect"] not in result["effects"]:
                    continue
                ev = step["evidence"]
                assert step["structure_share"] >= 0.5, path.name
                assert ev["heldout_gain"] >= 0.01 and ev["folds_improved"] >= ev["wins_needed"], path.name
                assert sign_test_p(ev["folds"], ev["folds_improved"]) <= 0.055, path.name
            assert np.linalg.norm(final) < 0.9 * np.linalg.norm(batch), path.name
        else:
            np.testing.assert_allclose(final, batch, rtol=0.02)  # the baseline's force fit is the batch fit's
        if result["time_base"] == "index":
            assert {s["effect"] for s in result["skipped"]} == {
                "time_lag",
                "clock_skew",
                "inertia",
                "payload_change",
                "payload_ramp",
            }
    log = results["axia80_ur_log_10hz"]
    assert log["effects"][0] == "time_lag" and log["final"]["params"]["time_lag"]["time_lag_s"] < -0.4
    assert np.linalg.norm(log["final"]["rms_force_S"]) < 0.5 * np.linalg.norm(log["batch_fit"]["rms_force_S"])
    assert results["lwr4_2013_06_12_tool"]["effects"] == []
    # the mount rotation it named second explains a quarter of what the model leaves without it (fz's 0.40 N
    # on the static poses, which nothing in the library explains): set aside, reported, not named
    poses = results["axia80_ur_100poses"]
    assert poses["effects"] == ["gain_crosstalk"]
    aside = [step for step in poses["steps"] if step["action"] == "set_aside"]
    assert [step["effect"] for step in aside] == ["mount_rotation"] and aside[0]["structure_share"] < 0.5


# ------------------------------------------------------------------ contact over much of a recording


def test_a_long_contact_is_gated_and_the_mount_under_it_named(tmp_path):
    """One 12 s, 3 N press in 30 s (41 % of the samples with its margins), along a fixed direction in B.

    A plain least-squares start absorbed it into the weight: nothing gated,
    force RMS 0.6-1.1 N, and the 2.7° mount under it not named.
    """
    contact = Indentation(start=8.0, duration=12.0, peak_force=3.0)
    result, world = run(tmp_path, "mount_rotation", seed=1, contacts=[contact])
    t = np.arange(0, 30, 1 / 250)
    in_contact = world.wrench(t, noise=False)["contact"]
    assert in_contact.mean() > 0.39
    assert result["gated"] >= in_contact.sum()
    pressed = np.linalg.norm(world.wrench(t, noise=False)["contact_force_S"], axis=1) > 0.5
    assert not np.any(result["_kept"] & pressed)
    assert result["effects"] == ["mount_rotation"]
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.05 * NOISE)
    assert result["warnings"] == {
        "saturated": False,
        "ringing": False,  # one press is contact
        "gated_on_contact_free": False,
        "gate_not_applied": False,
        "final_above_noise": False,
        "leftover": False,
    }


def test_too_much_contact_is_flagged_not_silent(tmp_path):
    """Ten 1.5 s presses every 3 s: half the recording and more in contact; the gate cannot apply and says so."""
    contacts = [Indentation(start=s, duration=1.5, peak_force=2.5) for s in np.arange(1.0, 30.0, 3.0)]
    result, _ = run(tmp_path, "none", seed=1, contacts=contacts)
    assert result["warnings"]["gate_not_applied"] and result["warnings"]["final_above_noise"]
    assert result["warnings"]["leftover"] and result["leftover"]["axes"]  # the presses, on their own axes too
    assert any("not applied" in note for note in result["notes"])
    assert any("the noise estimate" in note for note in result["notes"])
    assert max(result["final_rms_over_noise"]["force_S"]) > 1.5
    data = json.loads(json.dumps(json_ready(result)))
    assert data["warnings"]["gate_not_applied"] is True


# ------------------------------------------------------------------ short recordings


def test_the_fold_rule_is_a_sign_test():
    assert sign_test_p(10, 8) == pytest.approx(56 / 1024)
    assert [wins_needed(k, 0.8, 0.055) for k in (10, 9, 8, 7, 6, 5)] == [8, 8, 7, 7, 6, 5]
    assert wins_needed(4, 0.8, 0.055) == 5 and wins_needed(3, 0.8, 0.055) == 4  # cannot pass


def static_poses_csv(path, seed: int, n: int):
    """n static poses, t = rows, the paper's static model and nothing hidden (as the 100-pose Axia80 file)."""
    motion = StaticPoses(seed=seed, hold_s=1.0, move_s=2.0)
    world = SimWorld(motion=motion, seed=seed, inertia=False)
    t = motion.hold_midpoints(n)
    reading = world.wrench(t)
    np.savetxt(
        path,
        np.c_[np.arange(n), reading["force_S"], reading["torque_S"], quat_wxyz_from_matrix(world.pose(t)[0])],
        delimiter=",",
        header="t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz",
        comments="",
        fmt="%.10g",
    )


@pytest.mark.parametrize(("n", "seeds"), [(30, (113, 127, 143, 100, 101)), (60, (127, 133, 102))])
def test_short_clean_recordings_name_nothing(tmp_path, n, seeds):
    """With 3 folds "80 % of folds" was 3 of 3, which a candidate that explains nothing reaches 12.5 % of the
    time: these seeds named gain_crosstalk or mount_rotation. Short files now get 5 smaller folds and 5 of 5."""
    for seed in seeds:
        path = tmp_path / f"poses_{seed}.csv"
        static_poses_csv(path, seed, n)
        result = discrepancy(path)
        assert result["effects"] == [], (seed, result["rounds"])
        assert result["rounds"][0][0]["folds"] == 5 and result["rounds"][0][0]["wins_needed"] == 5


def test_too_few_folds_can_name_nothing_and_say_so(tmp_path):
    path = tmp_path / "drift.csv"
    write_csv(world_for("bias_drift", 1), path, 30.0, 250.0)
    result = discrepancy(path, Settings(folds=4))
    assert result["effects"] == [] and result["rounds"][0][0]["wins_needed"] == 5
    assert any("nothing can be named" in note for note in result["notes"])


# ------------------------------------------------------------------ uneven stamps, sensor offset


def test_jittered_timestamps_and_hidden_inertia(tmp_path):
    """Stamps ±30 % of a period off the grid: the derivatives use the real time steps (the uniform filter left
    the force RMS at 1.04-1.10x the noise)."""
    world = world_for("inertia", 1)
    rng = np.random.default_rng(1)
    t = np.sort(np.arange(7500) / 250 + rng.uniform(-0.3, 0.3, 7500) / 250)
    reading = world.wrench(t)
    R_BE, p = world.pose(t)
    path = tmp_path / "jitter.csv"
    np.savetxt(
        path,
        np.c_[t, reading["force_S"], reading["torque_S"], quat_wxyz_from_matrix(R_BE), p],
        delimiter=",",
        header="t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz,px,py,pz",
        comments="",
        fmt="%.10g",
    )
    result = discrepancy(path)
    assert result["effects"] == ["inertia"]
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.02 * NOISE), result["final"]


def test_a_sensor_offset_from_the_flange_is_identified(tmp_path):
    """The sensor origin 5 cm out along the flange axis: inertia names it (α × p), the gap closes."""
    path = tmp_path / "offset.csv"
    world = SimWorld(
        sensor=SensorParams(p_EoSo_E=(0.0, 0.0, 0.05)),
        inertia=True,
        seed=2,
        motion=RandomTour(seed=2, segment_s=1.0, max_translation=0.05),
    )
    write_csv(world, path, 30.0, 250.0)
    result = discrepancy(path)
    assert result["effects"] == ["inertia"]
    np.testing.assert_allclose(result["final"]["params"]["inertia"]["sensor_offset_S"], [0, 0, 0.05], atol=0.005)
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.02 * NOISE), result["final"]


# ------------------------------------------------------------------ Gauss-Newton


def test_gauss_newton_never_ends_worse_than_it_started(tmp_path):
    """From a start far off (a lag of 60 ms against a true 8 ms, a 10° mount), every call ends no worse."""
    path = tmp_path / "lag.csv"
    write_csv(world_for("time_lag", 2), path, 10.0, 250.0)
    d = Identification(load_stream(path))
    from hapticlab.core.sensor_model import Model
    from hapticlab.plugins.effects.mount_rotation import MountRotation
    from hapticlab.plugins.effects.time_lag import TimeLag

    lag = TimeLag()
    assert lag.check(d.motion) is None
    model = Model([("time_lag", lag), ("mount_rotation", MountRotation())])
    truth = world_for("time_lag", 2).truth()
    theta = np.concatenate(
        [
            truth["gravity_force_B"],
            truth["bias_force_S"],
            truth["cog_S"],
            truth["bias_torque_S"],
            [0.06],
            np.deg2rad([6.0, -6.0, 5.0]),
        ]
    )
    d.weights = 1 / np.array([NOISE] * 3 + [0.01] * 3)

    def costs(th):
        r = (d.y_fit - model.predict6(d.fit_motion, th)) * d.weights
        return np.sum(r[:, :3] ** 2), np.sum(r[:, 3:] ** 2)

    for _ in range(3):
        out = d.gauss_newton(model, theta, max_iter=2)
        assert costs(out)[0] <= costs(theta)[0] * (1 + 1e-9)
        theta = out


def _add_to_column(path, column: str, values: np.ndarray) -> None:
    """Add ``values`` (one per row) to a CSV column, the other columns left as written."""
    lines = path.read_text().splitlines()
    k = lines[0].split(",").index(column)
    out = [lines[0]]
    for line, v in zip(lines[1:], values):
        cells = line.split(",")
        cells[k] = repr(float(cells[k]) + float(v))
        out.append(",".join(cells))
    path.write_text("\n".join(out) + "\n")


def test_a_leftover_on_a_quiet_axis_is_flagged_against_that_axis_s_own_noise(tmp_path):
    """A sensor whose z force channel is four times quieter (0.03 N) and, on that channel only, a slow swing no
    effect of the library models (a cable pulling 0.05 N at 0.2 Hz). Against one noise figure for the three
    force axes (their RMS, 0.1 N) the z residual is under half of it: the old warning (above 1.5x) was silent.
    Against z's own noise it is ~1.5x, well over the threshold (1.05x at 7 500 samples): the report flags fz
    and only fz, names no effect, and says where it lives (0.2 Hz, all along; a push from 12 to 18 s instead:
    in those seconds). The same recording without either flags nothing."""
    from hapticlab.sessions.discrepancy.leftover import leftover_threshold

    world = SimWorld(
        sensor=SensorParams(noise_force_S=np.array([0.12, 0.12, 0.03])),
        motion=RandomTour(seed=31, segment_s=1.0, max_translation=0.05),
        seed=31,
        inertia=False,
    )
    path = tmp_path / "quiet_z.csv"
    write_csv(world, path, 30.0, 250.0)
    clean = discrepancy(path)
    assert clean["leftover"]["axes"] == [] and not clean["warnings"]["leftover"] and clean["effects"] == []
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0)
    _add_to_column(path, "fz", 0.05 * np.sin(2 * np.pi * 0.2 * t))
    result = discrepancy(path)
    assert result["effects"] == []
    assert result["leftover"]["axes"] == ["fz"] and result["warnings"]["leftover"]
    assert result["leftover"]["threshold"] == pytest.approx(leftover_threshold(result["usable"] - result["gated"]))
    assert result["leftover"]["rms_over_axis_noise"]["force_S"][2] > 1.4
    assert max(result["final_rms_over_noise"]["force_S"]) < 1.5 and not result["warnings"]["final_above_noise"]
    assert any("left on fz" in note for note in result["notes"])
    where = result["leftover"]["where"]["fz"]  # where it lives: at the swing's frequency, all along
    assert abs(where["peak_hz"] - 0.2) <= 1 / 30.0 and len(where["stretches"]) == 10
    # the same sensor with a 0.06 N push on fz from 12 to 18 s instead (below the contact gate's 6 sigma):
    # flagged, and placed in those seconds
    write_csv(world, path, 30.0, 250.0)
    _add_to_column(path, "fz", np.where((t > 12.0) & (t < 18.0), 0.06, 0.0))
    result = discrepancy(path)
    assert result["leftover"]["axes"] == ["fz"] and result["effects"] == []
    stretches = result["leftover"]["where"]["fz"]["stretches"]
    assert stretches and all(11.0 <= s["t_start"] and s["t_end"] <= 19.0 for s in stretches)


def test_parameter_errors_are_the_spread_over_seeds_and_what_the_motion_cannot_tell_is_named(tmp_path):
    """The final parameters' standard errors (``final.uncertainty.std``) against the spread of the estimates of
    a hidden 2.7° mount over eight seeds: the same size (the ratio within 0.6-1.6 per axis). And a tool turned
    about its own axis only (horizontal, along B's x): the weight's x component maps to the sensor's z at every
    roll, as the force bias along z does, so the two trade off exactly: the report names that pair, gives NaN
    for their errors (a number for every other parameter) and says so in a note."""
    from hapticlab.plugins.simworld.motion import AxialRotation

    errors, stds = [], []
    for seed in range(1, 9):
        result, _ = run(tmp_path, "mount_rotation", seed=seed)
        errors.append(np.array(result["final"]["params"]["mount_rotation"]["mount_rotation_SE"]) - MOUNT)
        stds.append([result["final"]["uncertainty"]["std"][f"mount_rotation.r{a}_rad"] for a in "xyz"])
    ratio = np.sqrt(np.mean(np.square(errors), axis=0)) / np.mean(stds, axis=0)
    assert np.all((0.6 < ratio) & (ratio < 1.6)), ratio

    world = SimWorld(
        motion=AxialRotation(speed_deg_s=90.0, duration=28.0, ramp_s=2.0, start_s=1.0), seed=3, inertia=False
    )
    path = tmp_path / "axial.csv"
    write_csv(world, path, 30.0, 250.0)
    result = discrepancy(path)
    lost = result["final"]["uncertainty"]["not_identifiable"]
    assert [sorted(c["parameters"]) for c in lost] == [["bias_force_S.z", "gravity_force_B.x"]]
    assert np.prod(lost[0]["weights"]) == pytest.approx(-1.0, abs=1e-6)  # equal and opposite: their sum is known
    std = result["final"]["uncertainty"]["std"]
    assert np.isnan(std["gravity_force_B.x"]) and np.isnan(std["bias_force_S.z"])
    assert all(np.isfinite(v) for k, v in std.items() if k not in ("gravity_force_B.x", "bias_force_S.z"))
    assert any(n.startswith("not identifiable from this motion: ") for n in result["notes"])


def test_held_out_gains_are_bounded_and_a_fit_that_does_not_carry_says_so(tmp_path):
    """Clean 60-pose files on which warm_up's held-out gain read -34, -103 and -340 (x100 %) as a ratio to the
    error without it: the fold holding the first rows, where a settling would be, cannot be predicted by a fit
    on the later ones. Every gain now lies in [-1, 1], and the candidate says why it is not fitted."""
    for seed in (104, 107, 110):
        path = tmp_path / f"poses_{seed}.csv"
        static_poses_csv(path, seed, 60)
        result = discrepancy(path)
        assert result["effects"] == []
        gains = [e["heldout_gain"] for rnd in result["rounds"] for e in rnd]
        assert all(np.isfinite(gains)) and all(-1.0 <= g <= 1.0 for g in gains), gains
        warm_up = next(e for e in result["rounds"][0] if e["effect"] == "warm_up")
        assert warm_up["heldout_gain"] < -0.9 and warm_up["note"].startswith("not fitted: its fit on the other folds")
