"""``hapticlab compensate`` and the command line around it."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from helpers import static_model_stream

from hapticlab.core.estimation.batch import batch_fit
from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.offline.compensate import compensate
from hapticlab.sessions.recording import load_stream, read_recording
from hapticlab.sessions.recording.csvimport import OUTPUT_COLUMNS

# README of ../shared/data/real: offline batch fit RMS per axis, N
AXIA80_LOG_BATCH_RMS = np.array([0.068, 0.257, 0.124])


def write_csv(path, n=3000, seed=11, contact=slice(1500, 1700)):
    block, truth = static_model_stream(n, seed=seed, noise_force=0.12, noise_torque=0.01)
    push = np.array([0.0, 1.0, 3.0])
    block.force_S[contact] += push
    block.torque_S[contact] += np.cross([0.0, 0.0, 0.25], push)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    with path.open("w") as fh:
        fh.write("t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n")
        for k in range(n):
            fh.write(
                ",".join(repr(float(v)) for v in [k * 1e-3, *block.force_S[k], *block.torque_S[k], *quat_BE[k]]) + "\n"
            )
    return truth, push


def test_compensate_csv_output_contract(tmp_path, capsys):
    truth, push = write_csv(tmp_path / "in.csv")
    code = main(
        [
            "compensate",
            str(tmp_path / "in.csv"),
            "-o",
            str(tmp_path / "out.csv"),
            "--params-out",
            str(tmp_path / "p.json"),
            "--set",
            "estimator.force_threshold=1.5",
        ]
    )
    assert code == 0
    with (tmp_path / "out.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == OUTPUT_COLUMNS and len(rows) == 3001
    table = np.array(rows[1:], dtype=float)
    assert np.allclose(table[:, 0], np.arange(3000) * 1e-3)
    assert set(np.unique(table[:, 7:])) <= {0.0, 1.0}
    contact = table[:, 7].astype(bool)
    assert contact[1500:1700].all() and contact.sum() == 200
    assert np.abs(table[1500:1700, 1:4] - push).mean() < 0.15
    params = json.loads((tmp_path / "p.json").read_text())
    for key in ("gravity_force_B", "bias_force_S", "cog_S", "bias_torque_S"):
        assert len(params[key]) == 3
    assert np.allclose(params["gravity_force_B"], truth["gravity_force_B"], atol=0.02)
    assert np.allclose(params["cog_S"], truth["cog_S"], atol=0.002)
    assert "RMS contact wrench on no-contact rows after convergence" in capsys.readouterr().err


def test_compensate_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "bad.csv").write_text("t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n0,1,2,3,4,5,6,1,0,0,0\n1,1,2,x,4,5,6,1,0,0,0\n")
    assert main(["compensate", str(tmp_path / "bad.csv"), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "hapticlab compensate: error: bad.csv line 3, column 'fz': 'x' is not a finite number"
    write_csv(tmp_path / "in.csv", n=50)
    assert (
        main(["compensate", str(tmp_path / "in.csv"), "-o", str(tmp_path / "o.csv"), "--set", "estimator.gain=2"]) == 2
    )
    assert "estimator.gain: unknown option" in capsys.readouterr().err
    assert main(["compensate", str(tmp_path / "in.csv"), "-o", str(tmp_path / "o.csv"), "--estimator", "nope"]) == 2
    assert "estimator.name: unknown estimator 'nope'" in capsys.readouterr().err


def test_compensate_a_recording_matches_the_live_session(tmp_path):
    # rls in its information form on both sides: the default, Algorithm 1's printed update, turns the live and
    # offline poses' 1e-7 N difference (below) into other convergence decisions (678 flags of 7001 on this run,
    # 30 contact flags; the force still within 0.0024 N), which would hide the pipeline difference this is for
    form = "covariance_update=information"
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", "session.duration=7.0", f"shadows.rls.{form}"])
    result = run_session(build_session(config), out=tmp_path / "live.mcap")
    offline = compensate(result.path, tmp_path / "offline.csv", overrides=[f"estimator.{form}"])
    live = read_recording(result.path)
    live_force = live.field("/estimator/rls", "contact_force_S")
    assert offline.rows == result.samples == len(live_force)
    # Live, samples newer than the last pose use one period of extrapolation;
    # offline, every sample is interpolated. The difference is tiny.
    assert np.sqrt(np.mean((offline.estimates.contact_force_S - live_force) ** 2)) < 0.01
    # The contact segments are the same. A sample whose residual lies within that tiny difference of the
    # threshold may flip (seen on one CPU: one sample of 7001, 4e-7 N apart), so a flag may differ only
    # next to a segment's edge, a boundary moved by one sample, and only a few times.
    off, on = offline.estimates.contact, live.field("/estimator/rls", "contact").astype(bool)
    edges = np.flatnonzero(np.diff(off.astype(np.int8)))  # the flag changes between samples k and k + 1
    differ = np.flatnonzero(off != on)
    assert len(differ) <= 3 and off.sum() > 500
    assert all(np.any((edges >= k - 1) & (edges <= k)) for k in differ), differ


def test_batch_estimator_offline_equals_batch_fit(tmp_path):
    write_csv(tmp_path / "in.csv", n=1200, contact=slice(0, 0))
    result = compensate(tmp_path / "in.csv", tmp_path / "out.csv", estimator_name="batch")
    s = load_stream(tmp_path / "in.csv").samples
    fit = batch_fit(s.force_S, s.torque_S, s.R_EB)
    for key in ("gravity_force_B", "bias_force_S", "cog_S", "bias_torque_S"):
        assert np.allclose(result.params[key], fit[key], atol=1e-9), key
    # the last row used every sample: its residual is the batch fit's
    assert np.allclose(result.estimates.contact_force_S[-1], fit["residual_force_S"][-1], atol=1e-9)


def test_real_axia80_log_within_10_percent_of_the_offline_batch_fit(real_data, tmp_path):
    """The bar the estimator is held to: the online force RMS (after convergence, as a
    vector magnitude) at most 10 % above the offline batch fit of the whole file."""
    result = compensate(real_data / "axia80_ur_log_10hz.csv", tmp_path / "out.csv")
    assert result.first_converged_force is not None
    rms_norm = float(np.sqrt(np.sum(np.square(result.rms_force_S))))
    assert rms_norm <= 1.10 * float(np.linalg.norm(AXIA80_LOG_BATCH_RMS)), result.rms_force_S


def test_plugins_command_lists_the_builtins(capsys):
    assert main(["plugins"]) == 0
    text = capsys.readouterr().out
    for kind, name in [
        ("sensor", "sim"),
        ("kinematics", "sim"),
        ("estimator", "rls"),
        ("estimator", "batch"),
        ("haptic_output", "null"),
    ]:
        assert any(kind in line and f" {name} " in line for line in text.splitlines()), (kind, name)


def test_run_command_writes_an_mcap(tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    assert main(["run", "--duration", "0.5", "--out", str(out), "--set", "session.realtime=false"]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert len(read_recording(out).topics["/sensor/wrench"]) == 501


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "nosuchpreset"], "unknown session 'nosuchpreset'"),
        (
            ["run", "--set", "shadows.rls.force_threshold=-1", "--duration", "0.1"],
            "shadows.rls.force_threshold: must be a finite number > 0, got -1.0",
        ),
        (["run", "--set", "bogus"], "--set 'bogus': expected key=value"),
        (["run", "--set", "haptic.max_force=-1"], "haptic.max_force: must be a finite number > 0 (N), got -1"),
        (
            ["run", "--set", "haptic.max_force_rate=nan"],
            "haptic.max_force_rate: must be a finite number > 0 (N/s), got nan",
        ),
        (
            ["run", "--set", "session.loop_rate_hz=0"],
            "session.loop_rate_hz: must be a finite number >= 100 and <= 10000 (Hz), got 0",
        ),
        (
            ["run", "--set", "session.loop_rate_hz=1e-6"],
            "session.loop_rate_hz: must be a finite number >= 100 and <= 10000 (Hz), got 1e-06",
        ),
    ],
)
def test_run_errors_are_one_line(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and err.startswith("hapticlab run: error: ")


def test_compensate_mcap_skips_unusable_rows(tmp_path):
    """A NaN, a saturated sample and rows past the pose stream never reach the estimator."""
    from hapticlab.sessions.recording import Recorder

    block, _ = static_model_stream(1500, seed=12, noise_force=0.1, noise_torque=0.008)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    path = tmp_path / "synthetic.mcap"
    with Recorder(path) as rec:
        for k in range(1500):
            t = k * 1_000_000
            force = block.force_S[k].tolist()
            if k == 1200:
                force[1] = float("nan")
            rec.write(
                "/sensor/wrench",
                t,
                {"force_S": force, "torque_S": block.torque_S[k].tolist(), "seq": k, "status": 1 if k == 1300 else 0},
            )
            if k < 1490:  # poses (one per sample here) stop 10 ms before the wrench stream
                rec.write("/kinematics/pose", t, {"quat_BE": quat_BE[k].tolist(), "p_BoEo_B": None, "joints": None})
    result = compensate(path, tmp_path / "out.csv")
    force = result.estimates.contact_force_S
    bad = np.zeros(1500, dtype=bool)
    bad[[1200, 1300]] = True
    bad[1491:] = True  # beyond one kinematics period (1 ms) after the last pose
    assert np.isnan(force[bad]).all() and np.isfinite(force[~bad]).all()
    assert result.estimates.converged_force[1200] == result.estimates.converged_force[1199]
    assert np.isfinite(result.rms_force_S).all() and max(result.rms_force_S) < 0.15
    assert any("11 sample(s) not used" in note for note in result.notes)


def test_compensate_guards_its_outputs(tmp_path, capsys):
    write_csv(tmp_path / "in.csv", n=100)
    assert main(["compensate", str(tmp_path / "in.csv"), "-o", str(tmp_path / "in.csv")]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert (
        main(
            [
                "compensate",
                str(tmp_path / "in.csv"),
                "-o",
                str(tmp_path / "o.csv"),
                "--params-out",
                str(tmp_path / "nope" / "p.json"),
            ]
        )
        == 2
    )
    assert "does not exist" in capsys.readouterr().err and not (tmp_path / "o.csv").exists()
    assert (
        main(
            [
                "compensate",
                str(tmp_path / "in.csv"),
                "-o",
                str(tmp_path / "o.csv"),
                "--set",
                "estimator.name=batch",
                "--params-out",
                str(tmp_path / "p.json"),
            ]
        )
        == 0
    )
    assert json.loads((tmp_path / "p.json").read_text())["estimator"] == "batch"


def test_epoch_times_keep_their_precision_and_blank_lines_are_ignored(tmp_path):
    write_csv(tmp_path / "in.csv", n=200)
    lines = (tmp_path / "in.csv").read_text().splitlines()
    epoch = [lines[0]] + [f"{1732233600.0 + k * 1e-3!r}" + line[line.index(",") :] for k, line in enumerate(lines[1:])]
    (tmp_path / "epoch.csv").write_text("\n".join(epoch) + "\n\n\n")
    compensate(tmp_path / "epoch.csv", tmp_path / "out.csv")
    t = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1, usecols=0)
    assert len(t) == 200 and np.all(np.diff(t) > 0)
    assert np.allclose(t, 1732233600.0 + np.arange(200) * 1e-3, rtol=0, atol=1e-6)


def reference_output(path, estimator_name="rls") -> bytes:
    """The output of compensate as it was before it streamed (the whole file in memory, one pass of blocks
    of 1024 usable rows), written the same way: the oracle the streamed output must equal byte for byte."""
    from hapticlab.core.host.registry import Registry

    stream = load_stream(path)
    estimator = Registry().create("estimator", estimator_name, {}, where="estimator")
    n, ok = len(stream), stream.samples.usable
    usable = np.flatnonzero(ok)
    force, torque = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    flags = np.zeros((n, 3), dtype=bool)
    for i in range(0, len(usable), 1024):
        rows = usable[i : i + 1024]
        est = estimator.update_block(stream.samples.subset(rows))
        force[rows], torque[rows] = est.contact_force_S, est.contact_torque_S
        flags[rows] = np.column_stack([est.contact, est.converged_force, est.converged_torque])
    last = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
    seen = last >= 0
    flags[seen, 1:] = flags[last[seen], 1:]
    lines = [",".join(OUTPUT_COLUMNS)]
    for t, values, f in zip(stream.t_s.tolist(), np.column_stack([force, torque]).tolist(), flags.astype(int).tolist()):
        lines.append(f"{t!r}," + ",".join(f"{v:.9g}" for v in values) + f",{f[0]},{f[1]},{f[2]}")
    return ("\n".join(lines) + "\n").encode()


def write_mcap_with_gaps(path, n=1500, seed=12):
    """A recording whose stream has a NaN, a flagged sample and rows past the pose stream."""
    from hapticlab.sessions.recording import Recorder

    block, _ = static_model_stream(n, seed=seed, noise_force=0.1, noise_torque=0.008)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    with Recorder(path) as rec:
        for k in range(n):
            t = k * 1_000_000
            force = block.force_S[k].tolist()
            if k in (200, 1200):
                force[1] = float("nan")
            rec.write(
                "/sensor/wrench",
                t,
                {
                    "force_S": force,
                    "torque_S": block.torque_S[k].tolist(),
                    "seq": k,
                    "status": 1 if k in (700, 1300) else 0,
                },
            )
            if k < n - 10:
                rec.write("/kinematics/pose", t, {"quat_BE": quat_BE[k].tolist(), "p_BoEo_B": None, "joints": None})
    return path


@pytest.mark.parametrize("rows", [700, 1024, 5000])
def test_the_streamed_output_is_the_whole_file_output(tmp_path, monkeypatch, rows):
    """compensate reads, estimates and writes chunk by chunk; whatever the chunk size (shorter than a block,
    a block, several blocks and a tail) the output is the one the whole file in memory gave, byte for byte."""
    import hapticlab.sessions.offline.compensate as module
    from hapticlab.sessions.recording import loader

    monkeypatch.setattr(module, "iter_stream", lambda path: loader.iter_stream(path, rows))
    write_csv(tmp_path / "in.csv", n=4100)
    write_mcap_with_gaps(tmp_path / "gaps.mcap")
    for source, name in (
        (tmp_path / "in.csv", "rls"),
        (tmp_path / "in.csv", "kalman"),
        (tmp_path / "gaps.mcap", "rls"),
    ):
        out = tmp_path / f"{source.stem}_{name}.csv"
        result = compensate(source, out, estimator_name=name, params_out=tmp_path / f"{out.stem}.json")
        assert out.read_bytes() == reference_output(source, name), (source.name, name)
        whole = compensate(load_stream(source), tmp_path / f"whole_{out.name}", estimator_name=name)
        assert result.first_converged_force == whole.first_converged_force
        np.testing.assert_allclose(result.rms_force_S, whole.rms_force_S, rtol=1e-12)
        for key in ("contact_force_S", "converged_force", "converged_torque"):
            np.testing.assert_array_equal(getattr(result.estimates, key), getattr(whole.estimates, key))
        assert json.loads((tmp_path / f"{out.stem}.json").read_text())["samples"] == len(load_stream(source))
    assert result.notes == ["gaps.mcap: 13 sample(s) not used (stale orientation, sensor status or non-finite)"]


def test_a_chunk_without_usable_rows_carries_the_flags_over(tmp_path):
    """estimate_chunks on chunks cut anywhere, one of them with no usable row: the flags of the usable row
    before an unusable one, across chunk boundaries."""
    from hapticlab.core.host.registry import Registry
    from hapticlab.sessions.offline.compensate import estimate_chunks, run_estimator
    from hapticlab.sessions.recording.loader import iter_stream

    path = write_mcap_with_gaps(tmp_path / "gaps.mcap", n=2600)
    whole = run_estimator(load_stream(path), Registry().create("estimator", "rls", {}, where="estimator"))
    chunks = list(iter_stream(path, rows=100))
    bad = chunks[7]
    chunks[7] = type(bad)(
        bad.t_s,
        type(bad.samples)(
            **{
                **{f: getattr(bad.samples, f) for f in bad.samples.__slots__},
                "status": np.ones(len(bad), dtype=np.int64),
            }
        ),
        [],
        bad.source,
    )
    parts = list(estimate_chunks(chunks, Registry().create("estimator", "rls", {}, where="estimator")))
    assert [len(s) for s, _ in parts] == [len(c) for c in chunks]
    conv = np.concatenate([e.converged_force for _, e in parts])
    assert np.isnan(parts[7][1].contact_force_S).all()
    assert (parts[7][1].converged_force == parts[6][1].converged_force[-1]).all()
    before, after = slice(0, 700), slice(800, None)
    np.testing.assert_array_equal(conv[before], whole.converged_force[before])
    assert conv[after].any()


def test_compensate_keeps_nothing_per_row_when_asked(tmp_path):
    write_csv(tmp_path / "in.csv", n=300)
    result = compensate(tmp_path / "in.csv", tmp_path / "o.csv", keep_estimates=False)
    assert result.estimates is None and result.rows == 300
