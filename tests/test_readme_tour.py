"""README.md's tour runs as written: its commands, in order, in a fresh folder, beside the files it shows.

The tour is the first ``sh`` block under "## A first tour"; every line of it that is not a comment is one
command, run by bash as a user would type it. The files the tour uses are shown in full in the same
section, each in a block introduced by a paragraph that starts with the file's name in backticks
(`` `my_session.toml`, a session of your own ``); they are saved first, as the README asks.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

from helpers import ROOT

README = ROOT / "README.md"
COMMAND_TIMEOUT_S = 1200
"""A whole command's budget (the slowest, ``review`` of a folder on Dask, takes seconds on an idle machine)."""


def tour_section(text: str) -> str:
    """The text of the README's "A first tour" section."""
    return text.split("\n## A first tour\n", 1)[1].split("\n## ", 1)[0]


def tour_commands(text: str) -> list[str]:
    """The tour's command lines, as written (their trailing comments included: bash ignores them)."""
    block = re.search(r"```sh\n(.*?)```", tour_section(text), flags=re.S)
    assert block, "README.md: no ```sh block under '## A first tour'"
    return [line for line in block.group(1).splitlines() if line.strip() and not line.lstrip().startswith("#")]


def tour_files(text: str) -> dict[str, str]:
    """The files the tour section shows in full: ``{name: content}``."""
    section, files = tour_section(text), {}
    for intro in re.finditer(r"^`([\w.-]+)`,", section, flags=re.M):
        block = re.compile(r"```\w+\n(.*?)```", flags=re.S).search(section, intro.end())
        assert block, f"README.md: `{intro.group(1)}` is introduced but not shown"
        files[intro.group(1)] = block.group(1)
    return files


def run_shell(run_command, command: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run one command line in bash in ``cwd``, with this interpreter's ``hapticlab`` first on the PATH
    (``run_command``: the conftest fixture, a command that runs to its end)."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return run_command(["bash", "-c", command], f"README: {command}", timeout=COMMAND_TIMEOUT_S, cwd=cwd, env=env)


def test_the_readme_is_read_in_five_minutes():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 300


def test_the_tour_and_its_files_are_found():
    text = README.read_text(encoding="utf-8")
    commands = tour_commands(text)
    assert len(commands) >= 10
    assert commands[0].startswith("hapticlab plugins")
    files = tour_files(text)
    assert set(files) == {"my_session.toml", "poses.csv"}
    session = tomllib.loads(files["my_session.toml"])
    assert session["session"]["out"] == "my_session.mcap" and session["session"]["realtime"] is False
    header, *rows = files["poses.csv"].splitlines()
    assert header == "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz" and len(rows) == 8
    # every file the tour reads and did not make is one the README shows
    for name in ("my_session.toml", "poses.csv"):
        assert any(name in command for command in commands)


def test_every_command_of_the_tour_runs_as_written(tmp_path, run_command):
    text = README.read_text(encoding="utf-8")
    for name, content in tour_files(text).items():
        (tmp_path / name).write_text(content, encoding="utf-8")
    for command in tour_commands(text):
        done = run_shell(run_command, command, tmp_path)
        assert done.returncode == 0, f"README tour: {command!r} exited {done.returncode}:\n{done.stderr[-3000:]}"
    # what the tour says it writes
    assert len(list((tmp_path / "recordings").glob("demo-*.mcap"))) == 2
    for name in ("cohort.csv", "cohort.html", "my_session.mcap", "report.html", "contact.csv", "params.json"):
        assert (tmp_path / name).is_file(), name
    for name in ("replayed.mcap", "effects.json", "tool.csv", "tool.json", "fixed.mcap"):
        assert (tmp_path / name).is_file(), name
    assert len((tmp_path / "cohort.csv").read_text().splitlines()) == 3  # a header and a row per session


def test_the_python_example_runs(tmp_path, run_command):
    section = README.read_text(encoding="utf-8").split("\n## From Python\n", 1)[1].split("\n## ", 1)[0]
    example = re.search(r"```python\n(.*?)```", section, flags=re.S)
    assert example, "README.md: no ```python block under '## From Python'"
    done = run_shell(run_command, f"python - <<'EOF'\n{example.group(1)}EOF", tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert len(list((tmp_path / "recordings").glob("demo-*.mcap"))) == 1
