"""Training sessions end to end: tasks run on ``teleop-sim``, reviewed with ``--json``, checked against what the
recording's own topics say; the instructor's report in headless Chromium at a desk's and a phone's width."""

from __future__ import annotations

import csv
import io
import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import chromium_fit

from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.recording import open_recording
from hapticlab.sessions.review.cohort import csv_text, numbered, review_row
from hapticlab.sessions.review.skill_names import KEYS

SESSIONS = {  # file stem: (trainee, task, seed)
    "t1-retraction": ("t1", "retraction", 11),
    "t2-retraction": ("t2", "retraction", 12),
    "t3-retraction": ("t3", "retraction", 13),
    "t1-palpation": ("t1", "palpation", 11),
}


@pytest.fixture(scope="module")
def cohort(tmp_path_factory, long_session) -> Path:
    folder = tmp_path_factory.mktemp("cohort")
    for stem, (trainee, task, seed) in SESSIONS.items():
        config, _ = load_config("teleop-sim")
        config = apply_overrides(config, [f"task.name={task}", f"session.trainee={trainee}", f"world.seed={seed}"])
        long_session(build_session(config), out=folder / f"{stem}.mcap")
    return folder


def reviewed(path: Path, tmp_path: Path) -> dict:
    out = tmp_path / f"{path.stem}.json"
    assert main(["review", str(path), "--json", str(out)]) == 0
    return json.loads(out.read_text())


def from_the_topics(path: Path) -> dict:
    """What an independent reader finds in the recording: the contact force each command was made from, the
    time the commands say was in contact, the path of the robot's targets."""
    rec = open_recording(path)
    commands = list(rec.messages("/haptic/command"))
    t = np.array([t for t, _ in commands]) / 1e9
    force = np.array([np.nan if m.get("contact_force_N") is None else m["contact_force_N"] for _, m in commands])
    contact = np.array([bool(m.get("contact")) for _, m in commands])
    tick = np.median(np.diff(t))
    targets = np.array([m["pose"]["p_BoEo_B"] for _, m in rec.messages("/robot/target")])
    return {
        "peak_force_N": float(np.nanmax(force)),
        "contact_time_s": float(contact.sum() * tick),
        "path_length_m": float(np.linalg.norm(np.diff(targets, axis=0), axis=1).sum()),
    }


@pytest.mark.parametrize("stem", list(SESSIONS))
def test_review_json_has_every_metric_consistent_with_the_recording(cohort, tmp_path, stem):
    got = reviewed(cohort / f"{stem}.mcap", tmp_path)
    trainee, task, _ = SESSIONS[stem]
    assert got["trainee"] == trainee and got["task"] == task
    assert set(KEYS) <= set(got) and all(got[k] is not None for k in KEYS)
    own = from_the_topics(cohort / f"{stem}.mcap")
    assert got["peak_force_N"] == pytest.approx(own["peak_force_N"], rel=0.05)
    assert got["contact_time_s"] == pytest.approx(own["contact_time_s"], rel=0.05)
    assert got["path_length_m"] == pytest.approx(own["path_length_m"], rel=1e-3)
    assert 1.5 < got["peak_force_N"] < 6.0 and got["contact_time_s"] > 2.0  # the hand pressed into the tissue
    assert got["force_time_integral_Ns"] > got["contact_time_s"] * 1.0  # over 1 N on average while touching
    assert -4.0 < got["sparc"] < -1.0 and got["task_time_s"] > got["contact_time_s"]
    assert not [m for m in got["moments"] if m["kind"] == "dropout"]  # nothing took the force off the hand
    if task == "retraction":  # the simulated hand holds ~2 N for 3 s: inside the 1.5-2.5 N band most of it
        assert got["task_outcome"]["time_in_band_s"] > 1.0 and got["task_score"] > 50
    else:  # it found the inclusion: the mark within two radii of it, scored
        assert got["task_outcome"]["mark_error_m"] < 2 * got["task_settings"]["inclusion_radius"]
        assert got["task_score"] > 0 and any(m["kind"] == "mark" for m in got["moments"])


@pytest.mark.parametrize("width", [1400, 400])
def test_the_report_fits_a_desk_and_a_phone_in_headless_chromium(cohort, tmp_path, run_command, width):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "Debian's chromium is needed (README: apt-get install chromium)"
    html = tmp_path / "report.html"
    assert main(["review", str(cohort / "t1-palpation.mcap"), "--html", str(html), "--cohort", str(cohort)]) == 0
    page = html.read_text()
    order = [page.index(f'id="{part}"') for part in ("outcome", "moments", "metrics", "appendix")]
    assert order == sorted(order)  # the trainee's part first, the engineer's last
    assert "cohort median (1)" in page  # the folder's palpation sessions: this one
    chromium_fit(chromium, page, width, tmp_path, run_command)


def test_the_cohort_csv_numbers_each_trainees_sessions(cohort):
    rows = numbered([review_row(path) for path in sorted(cohort.glob("*.mcap"))])
    table = list(csv.DictReader(io.StringIO(csv_text(rows))))
    assert len(table) == len(SESSIONS)  # one row per session
    seen = {(r["trainee"], r["task"], int(r["session"])) for r in table}  # whole numbers
    assert seen == {("t1", "retraction", 1), ("t2", "retraction", 1), ("t3", "retraction", 1), ("t1", "palpation", 1)}
    assert all(r["peak_force_N"] and r["task_score"] for r in table)


def test_every_message_is_stamped_with_the_wall_clock(cohort):
    from mcap.reader import make_reader

    with open(cohort / "t1-retraction.mcap", "rb") as f:
        stamps = [m.log_time for _, _, m in make_reader(f).iter_messages()]
    assert stamps and all(abs(t - time.time_ns()) < 86_400e9 for t in (min(stamps), max(stamps)))


def test_the_metrics_do_not_depend_on_how_the_file_is_read(cohort, monkeypatch):
    """Columns a few chunks at a time (the default) and a message at a time (every target its own batch, the
    force folded every 997 samples): the same metrics and outcome."""
    from hapticlab.sessions.review import review
    from hapticlab.sessions.review import summary as summary_module

    path = cohort / "t1-palpation.mcap"
    fast = review(path, plots=False)
    monkeypatch.setattr(summary_module, "CHUNK_ROWS", 997)
    slow = review(path, plots=False, fast=False)
    for key in KEYS:
        assert slow.skill[key] == pytest.approx(fast.skill[key], rel=1e-9, abs=1e-12), key
    assert slow.outcome == pytest.approx(fast.outcome)
