"""``hapticlab review``: a session's report checked against the world that made it and against the
whole-array metrics; its page in headless Chromium; a cohort over a folder on Dask."""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import as_before_the_offset

from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.offline.metrics import error_stats
from hapticlab.sessions.recording import open_recording
from hapticlab.sessions.review import figures, review
from hapticlab.sessions.review import summary as summary_module
from hapticlab.sessions.review.report import session_page

# the demo world's contacts (sessions/presets/demo.toml): start s, duration s, peak N
DEMO_CONTACTS = [(6.0, 1.5, 3.0), (9.5, 1.5, 2.0), (12.5, 1.0, 4.0)]


def record(path: Path, *overrides: str, run=run_session) -> Path:
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", *overrides])
    run(build_session(config), out=path)
    return path


@pytest.fixture(scope="module")
def session(tmp_path_factory, long_session) -> Path:
    """The demo's 14 s (its three contacts; kalman drives, rls beside it), a trainee, a task and notes."""
    path = tmp_path_factory.mktemp("review") / "t07-palpation.mcap"
    return record(
        path,
        "session.duration=14",
        "session.trainee=T07",
        "session.task=palpation",
        'session.notes="first try <b>left hand</b>"',
        run=long_session,
    )


def test_contacts_are_found_where_the_world_put_them(session):
    r = review(session, force_limit=2.5, plots=False)
    assert (r.trainee, r.task, r.notes) == ("T07", "palpation", "first try <b>left hand</b>")
    assert r.samples == 14001 and r.lost_samples == 0 and r.bad_samples == 0
    assert r.sensor_rate_hz == pytest.approx(1000.0, rel=1e-3) and r.kinematics_rate_hz == pytest.approx(500, rel=0.01)
    assert len(r.contacts) == 3
    for contact, (start, duration, peak) in zip(r.contacts, DEMO_CONTACTS):
        # the estimator flags a contact once its force passes its 1 N threshold on the 0.3 s ramp
        assert start <= contact.start_s <= start + 0.3
        assert duration - 0.6 <= contact.duration_s <= duration
        # the largest of ~1000 noisy samples on the plateau: the world's peak plus a few noise stds
        # (0.12 N per axis, the demo sensor's), and the estimate's own error (~0.1 N)
        assert peak <= contact.peak_N <= peak + 5 * 0.12
        assert 0.5 * peak < contact.mean_N < peak
    assert r.peak_force_N == pytest.approx(max(c.peak_N for c in r.contacts))
    # the 2 N contact never passes 2.5 N; the 3 N and 4 N ones do, for most of their plateau
    assert r.contacts[1].over_limit_s == 0.0
    assert 0.3 < r.contacts[0].over_limit_s < 1.5 and 0.3 < r.contacts[2].over_limit_s < 1.0
    assert r.over_limit_s == pytest.approx(sum(c.over_limit_s for c in r.contacts), abs=0.01)
    assert r.complete and r.estimator == "kalman" and [e.name for e in r.estimators] == ["kalman", "rls"]


def test_the_streamed_figures_equal_the_whole_array_metrics(session, monkeypatch):
    monkeypatch.setattr(summary_module, "CHUNK_ROWS", 997)  # many chunks: the merge of running sums is exercised
    r = review(session, plots=False)
    rec = open_recording(session)
    t_aligned = rec.t_ns("/aligned/sample")
    raw_f, raw_t = rec.field("/aligned/sample", "force_S"), rec.field("/aligned/sample", "torque_S")
    for e in r.estimators:
        topic = f"/estimator/{e.name}"
        t = rec.t_ns(topic)
        row = np.searchsorted(t_aligned, t)
        assert np.array_equal(t_aligned[row], t)
        contact = rec.field(topic, "contact").astype(bool)
        for stage, (flag, raw, est, axes) in enumerate(
            (
                ("converged_force", raw_f, rec.field(topic, "contact_force_S"), ("fx", "fy", "fz")),
                ("converged_torque", raw_t, rec.field(topic, "contact_torque_S"), ("tx", "ty", "tz")),
            )
        ):
            first = int(np.argmax(rec.field(topic, flag).astype(bool)))
            rows = (np.arange(len(t)) >= first) & ~contact
            expected = error_stats(raw[row][rows], est[rows], axes)
            for axis in axes:
                for key, value in expected[axis].items():
                    assert e.table[axis][key] == pytest.approx(value, rel=1e-9, abs=1e-12), (e.name, axis, key)
                assert e.table[axis]["samples"] == rows.sum()
            when = (t[first] - r.start_ns) / 1e9
            assert (e.converged_force_s if stage == 0 else e.converged_torque_s) == pytest.approx(when)
        # the compensation works: after it, the no-contact error is a fraction of before
        assert all(e.table[a]["mae_after"] < 0.2 * e.table[a]["mae_before"] for a in ("fx", "fy", "fz"))


def test_the_chunk_reader_gives_the_message_readers_figures(session):
    fast, reference = review(session, fast=True), review(session, fast=False)
    assert len(fast.contacts) == len(reference.contacts) == 3
    for a, b in zip(fast.contacts, reference.contacts):
        assert a.__dict__ == pytest.approx(b.__dict__, rel=1e-12)
    for a, b in zip(fast.estimators, reference.estimators):
        assert (a.name, a.samples, a.converged_force_s, a.converged_torque_s, a.scored) == (
            b.name,
            b.samples,
            b.converged_force_s,
            b.converged_torque_s,
            b.scored,
        )
        for axis in a.table:
            assert a.table[axis] == pytest.approx(b.table[axis], rel=1e-12)
    assert [e.kind for e in fast.events] == [e.kind for e in reference.events]
    assert fast.series.params == reference.series.params
    for name in ("raw", "compensated", "contact_force", "command"):
        x, y = getattr(fast.series, name), getattr(reference.series, name)
        np.testing.assert_array_equal(x.count, y.count)
        np.testing.assert_allclose(x.mean, y.mean, rtol=1e-12, equal_nan=True)
        np.testing.assert_array_equal(x.hi, y.hi)


def test_the_chunk_reader_reads_what_the_recording_holds_at_7_khz(tmp_path):
    from hapticlab.sessions.recording.columnar import iter_chunks

    path = record(tmp_path / "7k.mcap", "session.duration=2", "sensor.rate_hz=7000")
    rec = open_recording(path)
    topics = ["/aligned/sample", "/estimator/rls", "/haptic/command"]
    got: dict[str, list] = {t: [] for t in topics}
    for chunk in iter_chunks(path, topics):
        for topic, batch in chunk.items():
            got[topic].append(batch)
    for topic in topics[:2]:
        t = np.concatenate([b["t_ns"] for b in got[topic]])
        np.testing.assert_array_equal(t, rec.t_ns(topic))
        assert len(t) > 13000  # 7 samples a tick, blocks of several lengths in each chunk
        for name in ("force_S",) if topic == "/aligned/sample" else ("contact_force_S", "contact", "converged_force"):
            np.testing.assert_array_equal(
                np.concatenate([b[name] for b in got[topic]]).astype(float), rec.field(topic, name).astype(float)
            )
    params = [p for b in got["/estimator/rls"] for p in b["params"]]
    recorded = [m["params"] for _, m in rec.messages("/estimator/rls") if m.get("params") is not None]
    assert [p for _, p in params] == recorded and len(params) >= 15
    commands = [m for b in got["/haptic/command"] for _, m in b]
    assert commands == [m for _, m in rec.messages("/haptic/command")]
    fields = {"force_D": 3, "enabled": 0}  # the same JSON read as columns by key, never decoded
    columns = [c["/haptic/command"] for c in iter_chunks(path, ["/haptic/command"], {"/haptic/command": fields})]
    np.testing.assert_array_equal(
        np.concatenate([c["force_D"] for c in columns]), np.array([m["force_D"] for m in commands], dtype=float)
    )
    np.testing.assert_array_equal(np.concatenate([c["enabled"] for c in columns]), [m["enabled"] for m in commands])
    np.testing.assert_array_equal(np.concatenate([c["t_ns"] for c in columns]), rec.t_ns("/haptic/command"))


def test_a_file_without_message_indexes_is_left_to_the_message_reader(tmp_path):
    from mcap.writer import IndexType, Writer

    from hapticlab.sessions.recording.columnar import can_read

    for index_types, readable in ((IndexType.ALL, True), (IndexType.NONE, False)):  # MCAP lets a writer omit them
        path = tmp_path / f"{index_types.name}.mcap"
        with open(path, "wb") as f:
            writer = Writer(f, index_types=index_types)
            writer.start()
            channel = writer.register_channel("/events", "json", writer.register_schema("e", "jsonschema", b"{}"))
            for k in range(10):
                writer.add_message(channel, k, b'{"kind": "a", "message": "b"}', k)
            writer.finish()
        assert can_read(path) is readable


def test_json_read_by_key_falls_back_to_decoding_when_a_message_lacks_the_key():
    from hapticlab.sessions.recording.columnar import _json_columns, picked

    messages = [
        {"force_D": [1.0, None, 3.0], "enabled": True, "reason": '"force_D":[9,9,9]'},
        {"enabled": False, "reason": "no force"},
    ]
    text = json.dumps(messages).encode()
    t = np.array([1, 2])
    assert _json_columns(text, t, {"force_D": 3, "enabled": 0}) is None  # the second has no force_D
    columns = picked(messages, t, {"force_D": 3, "enabled": 0})
    np.testing.assert_array_equal(columns["force_D"], [[1.0, np.nan, 3.0], [np.nan] * 3])
    np.testing.assert_array_equal(columns["enabled"], [True, False])
    first = _json_columns(json.dumps(messages[:1]).encode(), t[:1], {"force_D": 3, "enabled": 0})
    np.testing.assert_array_equal(first["force_D"], [[1.0, np.nan, 3.0]])  # the key inside a string is not a key


def test_json_read_by_key_finds_a_nested_key_and_strings_with_their_escapes():
    from hapticlab.sessions.recording.columnar import TEXT, _json_columns, picked

    targets = [
        {"pose": {"quat_BE": [1, 0, 0, 0], "p_BoEo_B": [0.1, 0.2, 0.3]}, "mode": "holding", "reason": 'clutch "3"'},
        {"pose": {"quat_BE": [1, 0, 0, 0], "p_BoEo_B": [0.4, 0.5, 0.6]}, "mode": "following", "reason": ""},
    ]
    fields = {"p_BoEo_B": 3, "mode": TEXT, "reason": TEXT}
    t = np.array([1, 2])
    found = _json_columns(json.dumps(targets).encode(), t, fields)
    decoded = picked(targets, t, fields)
    for columns in (found, decoded):  # read by key, and decoded: the same
        np.testing.assert_array_equal(columns["p_BoEo_B"], [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
        assert columns["mode"].tolist() == ["holding", "following"] and columns["reason"].tolist() == ['clutch "3"', ""]


def test_an_envelope_holds_every_samples_min_max_and_mean_per_bin():
    rng = np.random.default_rng(4)
    t = np.sort(rng.integers(0, 10_000, 5000))
    values = rng.normal(size=(5000, 2))
    values[::97, 1] = np.nan  # a non-finite value is left out of its bin's figures
    env = figures.Envelope(0, 10_000, 2, bins=37)
    for part in np.array_split(np.arange(5000), 7):  # in pieces, as a review adds them
        env.add(t[part], values[part])
    shuffled = figures.Envelope(0, 10_000, 2, bins=37)
    order = rng.permutation(5000)
    shuffled.add(t[order], values[order])  # out of time order: the other way through
    bins = np.clip(t * 37 // 10_000, 0, 36)
    for b in range(37):
        for k in range(2):
            x = values[bins == b, k]
            x = x[np.isfinite(x)]
            for e in (env, shuffled):
                assert e.count[b, k] == len(x)
                if len(x):
                    assert (e.lo[b, k], e.hi[b, k]) == (x.min(), x.max())
                    assert e.mean[b, k] == pytest.approx(x.mean(), rel=1e-12)


def test_cli_prints_the_review_writes_plots_and_a_page_and_never_overwrites(session, tmp_path, capsys):
    html, plots = tmp_path / "report.html", tmp_path / "plots"
    assert main(["review", str(session), "--html", str(html), "--plots", str(plots), "--force-limit", "2.5"]) == 0
    out = capsys.readouterr().out
    assert "trainee T07" in out and "task palpation" in out and "first try <b>left hand</b>" in out
    assert "compensation error" in out and "faults and fail-safes: none" in out
    import matplotlib.image

    for name in ("wrench", "convergence", "contact", "command"):
        image = matplotlib.image.imread(plots / f"{name}.png")
        assert image.shape[0] > 200 and image.shape[1] > 600 and image[..., :3].std() > 0.05  # drawn, not blank
    page = html.read_text()
    # self-contained: the force timeline and the four engineering plots of the appendix
    assert page.count("data:image/png;base64,") == 5 and 'src="http' not in page
    assert "first try &lt;b&gt;left hand&lt;/b&gt;" in page  # the notes escaped, not markup
    before = html.read_bytes()
    assert main(["review", str(session), "--html", str(html)]) == 2
    assert "already exists" in capsys.readouterr().err and html.read_bytes() == before
    assert main(["review", str(session), "--plots", str(plots)]) == 2
    assert main(["review", str(session), "--html", str(html), "--force"]) == 0


def test_the_page_renders_in_headless_chromium(session, tmp_path, run_command):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "Debian's chromium is needed (README: apt-get install chromium)"
    html = tmp_path / "report.html"
    assert main(["review", str(session), "--html", str(html)]) == 0
    flags = [
        chromium,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        f"--user-data-dir={tmp_path / 'profile'}",
    ]
    dom = run_command([*flags, "--dump-dom", html.as_uri()], "chromium --dump-dom", timeout=120).stdout
    for table_id in ("outcome", "metrics", "summary", "contacts", "estimators", "errors-rls", "errors-kalman"):
        assert f'id="{table_id}"' in dom, table_id
    assert dom.count("<tr>") > 30 and "T07" in dom
    shot = tmp_path / "shot.png"
    done = run_command(
        [*flags, "--window-size=1200,2400", f"--screenshot={shot}", html.as_uri()], "chromium --screenshot", timeout=120
    )
    assert done.returncode == 0, done.stderr
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.std() > 0.05  # text, tables and plots: not a blank page
    assert (pixels < 0.5).mean() > 0.01  # dark pixels: there is text on it


def test_a_session_without_its_end_is_reviewed_and_says_so(session, tmp_path):
    from hapticlab.sessions.recording import recover

    cut = tmp_path / "cut.mcap"
    data = session.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])  # killed: no summary, no end
    fixed = tmp_path / "fixed.mcap"
    recover(cut, fixed)
    r = review(fixed, plots=False)
    assert not r.complete and 0 < r.samples < 14001 and r.trainee == "T07"


def test_bad_inputs_get_one_line_and_status_2(tmp_path, capsys):
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    assert main(["review", str(text)]) == 2
    assert main(["review", str(tmp_path / "missing.mcap")]) == 2
    assert main(["review", str(text), "--force-limit", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("hapticlab review: error:") == 3 and "Traceback" not in err
    assert "no such file" in err and "--force-limit" in err


def test_a_cohort_in_parallel_on_an_existing_dask_cluster(session, tmp_path, capsys, dask_workers):
    from dask.distributed import LocalCluster

    folder = tmp_path / "cohort"
    (folder / "t08").mkdir(parents=True)
    shutil.copy(session, folder / "t07-1.mcap")
    record(
        folder / "t08" / "t08-1.mcap",
        "session.duration=8",
        "session.trainee=T08",
        "session.task=palpation",
        "world.seed=5",
    )
    (folder / "broken.mcap").write_text("not a recording\n")
    out_csv, html, parquet = tmp_path / "cohort.csv", tmp_path / "cohort.html", tmp_path / "cohort.parquet"
    with LocalCluster(n_workers=dask_workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        status = main(
            [
                "review",
                str(folder),
                "--csv",
                str(out_csv),
                "--html",
                str(html),
                "--parquet",
                str(parquet),
                "--scheduler",
                cluster.scheduler_address,
            ]
        )
    assert status == 2  # one file refused: said, and the others reviewed
    captured = capsys.readouterr()
    assert "broken.mcap" in captured.out and "2 worker(s)" in captured.err
    rows = list(csv.DictReader(io.StringIO(out_csv.read_text())))
    assert [(r["recording"], r["trainee"]) for r in rows] == [("t07-1.mcap", "T07"), ("t08/t08-1.mcap", "T08")]
    alone = review(session, plots=False)
    assert int(rows[0]["contacts"]) == len(alone.contacts) == 3
    assert float(rows[0]["peak_force_N"]) == pytest.approx(alone.peak_force_N, abs=1e-3)
    assert float(rows[1]["duration_s"]) == pytest.approx(8.0, abs=0.01) and int(rows[1]["contacts"]) == 1
    assert [r["session"] for r in rows] == ["1", "1"]  # each trainee's first session of the task
    known = next(e for e in alone.events if e.kind == "parameters_known")  # the gate's, not kalman's first flag
    assert float(rows[0]["parameters_known_s"]) == pytest.approx(alone.t_s(known.t_ns), abs=1e-3)
    assert alone.t_s(known.t_ns) > 1.0 > alone.primary.converged_force_s  # 0.00 in the old converged_s
    import pyarrow.parquet as pq

    assert pq.read_table(parquet).to_pydict()["recording"] == ["t07-1.mcap", "t08/t08-1.mcap"]
    page = html.read_text()
    assert 'id="cohort"' in page and 'id="refused"' in page and page.count("data:image/png;base64,") == 1
    assert "2 session(s), 2 trainee(s), 1 task(s)" in page


def test_a_teleoperation_review_shows_the_haptic_port_s_energy_and_damping(tmp_path, long_session):
    """teleop-sim with 300 ms of delay and the passivity controller on: the review reports the most energy the
    port put into the hand, as an independent sum of each command's force times the handle's next velocity
    gives it, and how often the controller damped; its command plot gains the energy and damping axis."""
    from hapticlab.sessions.recording import read_recording
    from hapticlab.sessions.review.plots import command, figure_png

    config, _ = load_config("teleop-sim")
    config = apply_overrides(config, ["teleop.delay_s=0.3", "teleop.passivity=on"])
    result = long_session(build_session(config), out=tmp_path / "teleop.mcap")
    rec = read_recording(result.path)
    force = np.array([m["force_D"] for _, m in rec.topics["/haptic/command"][:-1]])
    v = np.array([m["v_DHo_D"] for _, m in rec.topics["/haptic/state"]])
    n = min(len(force), len(v))
    energy = np.cumsum(np.einsum("ij,ij->i", force[: n - 1], v[1:n]) * 1e-3)  # J, at 1 kHz
    r = review(result.path)
    assert r.port_energy_max_J is not None and abs(r.port_energy_max_J - energy.max()) < 0.005
    assert r.damping_share is not None and 0.0 < r.damping_share < 1.0
    assert any(row[0] == "haptic port (passivity)" for row in summary_module_rows(r))
    plt, fig = command(r)
    assert len(fig.axes) == 4  # force, force on, energy and its twin (damping)
    assert figure_png(plt, fig).startswith(b"\x89PNG")
    demo = review(record(tmp_path / "demo.mcap", "session.duration=2.0"))
    assert demo.port_energy_max_J is None and demo.damping_share is None  # no teleoperation, no port row


def summary_module_rows(r):
    from hapticlab.sessions.review.page import summary_rows

    return summary_rows(r)


def test_a_review_reads_the_same_figures_from_unix_log_times_as_from_a_file_before_them(tmp_path):
    """Log times are Unix time now; the same session with its log times on the session clock (as files were
    written before) reviews to the same figures, page and times from the start (its first contact at 6 s)."""
    new = record(tmp_path / "new" / "s.mcap", "session.duration=8")
    (tmp_path / "old").mkdir()
    old = as_before_the_offset(new, tmp_path / "old" / "s.mcap")
    a, b = review(new, force_limit=2.5, plots=False), review(old, force_limit=2.5, plots=False)
    assert len(a.contacts) == 1 and 6.0 <= a.contacts[0].start_s <= 6.3
    assert a.start_ns == b.start_ns < 10**17  # the session clock either way
    assert (a.contacts, a.events, a.estimators) == (b.contacts, b.events, b.estimators)
    assert {**a.row(), "recording": ""} == {**b.row(), "recording": ""}
    assert session_page(a).replace(str(new), "") == session_page(b).replace(str(old), "")
