"""docs/api.md's examples run as written, in order, in a fresh folder; and the API's promises hold."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
from helpers import ROOT

import hapticlab

DOCS = ROOT / "docs" / "api.md"


def test_every_example_in_docs_api_runs(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", DOCS.read_text(), flags=re.S)
    assert len(blocks) >= 6
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(DOCS), "exec"), namespace)  # our own documentation
    path = namespace["path"]
    assert Path(path).is_file() and Path(path).parent.name == "recordings"
    assert namespace["config"]["estimator"]["name"] == "kalman"  # the demo's (rls beside it)
    out = namespace["out"]
    assert out.contact_force_S.shape == (3001, 3) and bool(out.converged_force[-1])
    assert (tmp_path / "rls_demo.mcap").is_file()
    printed = capsys.readouterr().out
    assert "session_start" in printed and "estimator rls" in printed


def test_run_returns_the_recording_and_open_recording_reads_it_back(tmp_path):
    path = hapticlab.run("demo", settings={"session.duration": 1, "session.realtime": False}, out=tmp_path / "api.mcap")
    rec = hapticlab.open_recording(path)
    assert rec.meta("hapticlab.summary", "samples") == 1001
    t_ns, force_S, _ = rec.wrench()
    messages = list(rec.messages("/sensor/wrench"))
    assert [t for t, _ in messages] == t_ns.tolist()
    assert np.array_equal([m["force_S"] for _, m in messages], force_S)
    # offline compensation of the recording reproduces the live estimates of the same estimator: live, a
    # sample newer than the last pose is held for up to one kinematics period, offline it is interpolated,
    # so they differ by far less than the sensor's 0.12 N noise
    live = rec.estimates("rls")
    offline = hapticlab.compensate(path, "rls")
    assert np.array_equal(live.contact, offline.contact)
    assert np.sqrt(np.mean((live.contact_force_S - offline.contact_force_S) ** 2)) < 0.01


def test_the_one_liner_of_the_issue(tmp_path, run_command):
    code = (
        "import hapticlab; p = hapticlab.run('demo', settings={'session.duration': 3, "
        "'session.realtime': False}); print(hapticlab.open_recording(p).metadata)"
    )
    done = run_command([sys.executable, "-c", code], "the one-liner", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "'hapticlab.session'" in done.stdout and "'hapticlab.summary'" in done.stdout


def test_make_estimator_checks_its_options():
    import pytest

    from hapticlab.core.host.registry import ConfigError

    assert hapticlab.make_estimator("rls", force_threshold=0.6).force_threshold == 0.6
    with pytest.raises(ConfigError, match=r"^estimator.force_treshold: unknown option"):
        hapticlab.make_estimator("rls", force_treshold=0.6)


def test_the_api_is_typed_and_exports_what_its_functions_return():
    """Every function of the facade is annotated, and the types it returns or raises are exported beside it
    (imported on first use)."""
    import inspect
    import typing

    import pytest

    exported = {name: getattr(hapticlab, name) for name in hapticlab.__all__}
    assert {"Recording", "Stream", "SessionError", "RecordingError", "Estimates", "Estimator"} <= set(exported)
    namespace = {**vars(hapticlab), **exported}
    functions = {name: value for name, value in exported.items() if inspect.isfunction(value)}
    assert set(functions) == {"compensate", "get_plugins", "load_session", "make_estimator", "open_recording", "run"}
    for name, function in functions.items():
        hints = typing.get_type_hints(function, globalns=namespace)
        assert "return" in hints and set(inspect.signature(function).parameters) <= set(hints), name
    assert typing.get_type_hints(hapticlab.open_recording, globalns=namespace)["return"] is hapticlab.Recording
    assert typing.get_type_hints(hapticlab.compensate, globalns=namespace)["return"] is hapticlab.Estimates
    assert typing.get_type_hints(hapticlab.make_estimator, globalns=namespace)["return"] is hapticlab.Estimator
    assert issubclass(hapticlab.SessionError, RuntimeError) and issubclass(hapticlab.RecordingError, ValueError)
    assert set(hapticlab.__all__) <= set(dir(hapticlab))
    with pytest.raises(AttributeError, match="no attribute 'Recordings'"):
        hapticlab.Recordings  # noqa: B018 - the attribute access is the test
