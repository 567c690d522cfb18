"""Folders of recordings, in parallel with Dask: the same results as one file at a time, bad files as rows."""

from __future__ import annotations

import shutil

import pytest

from hapticlab.core.errors import OutputExistsError
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.offline.folders import map_recordings, recordings_in
from hapticlab.sessions.offline.replay import replay, replay_folder
from hapticlab.sessions.recording import read_recording


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """Three short demo sessions (different worlds), one in a sub-folder, and a file that is no recording."""
    folder = tmp_path_factory.mktemp("archive")
    (folder / "trainee-b").mkdir()
    for k, name in enumerate(["a1.mcap", "a2.mcap", "trainee-b/b1.mcap"]):
        config, _ = load_config("demo")
        config = apply_overrides(config, ["session.realtime=false", "session.duration=3", f"world.seed={k + 3}"])
        run_session(build_session(config), out=folder / name)
    (folder / "notes.mcap").write_text("not a recording\n")
    return folder


def test_a_folder_replays_in_parallel_as_it_does_one_file_at_a_time(archive, tmp_path, dask_workers):
    out = tmp_path / "replayed"
    run = replay_folder(archive, "kalman", out, workers=dask_workers, progress=False)
    names = [str(o.path.relative_to(archive)) for o in run.outcomes]
    assert names == ["a1.mcap", "a2.mcap", "notes.mcap", "trainee-b/b1.mcap"]  # the order given
    assert (
        run.workers == dask_workers == 2 and len(run.peak_rss_mb) == 2 and all(v > 50 for v in run.peak_rss_mb.values())
    )
    bad = run.outcomes[2]
    assert bad.value is None and "notes.mcap" in bad.error and "\n" not in bad.error
    alone = replay(archive / "trainee-b" / "b1.mcap", "kalman")
    parallel = run.outcomes[3].value
    assert parallel["comparison"] == alone["comparison"] and parallel["rows"] == alone["rows"]
    new = read_recording(out / "trainee-b" / "b1.mcap")
    assert "/estimator/kalman" in new.topics and len(new.topics["/estimator/kalman"]) == alone["rows"]
    # the outputs are checked before any work: an existing one is refused, nothing replayed
    with pytest.raises(OutputExistsError, match=r"a1.mcap"):
        replay_folder(archive, "kalman", out, workers=1, progress=False)


def test_the_same_job_runs_on_an_existing_dask_cluster(archive, tmp_path, dask_workers):
    from dask.distributed import LocalCluster

    folder = tmp_path / "two"
    folder.mkdir()
    for name in ("a1.mcap", "a2.mcap"):
        shutil.copy(archive / name, folder / name)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        run = map_recordings(len_of_wrench, recordings_in(folder), scheduler=cluster.scheduler_address, progress=False)
    assert run.workers == 1
    assert [o.value for o in run.outcomes] == [3001, 3001]


def len_of_wrench(path) -> int:
    return len(read_recording(path).topics["/sensor/wrench"])


def test_a_folder_without_recordings_and_an_absent_scheduler_are_one_line(tmp_path):
    with pytest.raises(ValueError, match=r"no .mcap recordings"):
        recordings_in(tmp_path)
    (tmp_path / "x.mcap").write_bytes(b"")
    with pytest.raises(ValueError, match=r"--scheduler tcp://127.0.0.66:1: no Dask scheduler answered"):
        map_recordings(len_of_wrench, [tmp_path / "x.mcap"], scheduler="tcp://127.0.0.66:1", progress=False)


def test_a_folder_goes_through_the_discrepancy_workflow_as_one_file_does(archive, dask_workers):
    from hapticlab.sessions.discrepancy.report import json_ready
    from hapticlab.sessions.discrepancy.workflow import discrepancy, discrepancy_folder

    run = discrepancy_folder(archive, workers=dask_workers, progress=False)
    assert [o.error == "" for o in run.outcomes] == [True, True, False, True]
    alone = json_ready(discrepancy(archive / "a2.mcap"))
    assert run.outcomes[1].value == alone  # the same result, effects named and all
