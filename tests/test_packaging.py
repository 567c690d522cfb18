"""Every package folder ends up in the wheel; presets ship as package data."""

from __future__ import annotations

import shutil
import sys
import zipfile

import pytest
from helpers import ROOT

SKIP = {"tests", "bench", "docs", "build", "dist", ".venv", ".git"}


def package_folders() -> set[str]:
    """Import names of every folder below the root that has an __init__.py."""
    names = {"hapticlab"}
    for init in ROOT.rglob("__init__.py"):
        rel = init.parent.relative_to(ROOT)
        if rel.parts and (
            rel.parts[0] in SKIP or rel.parts[0].startswith(".") or any(p.endswith(".egg-info") for p in rel.parts)
        ):
            continue
        if rel.parts:
            names.add(".".join(("hapticlab", *rel.parts)))
    return names


@pytest.fixture(scope="module")
def wheel(tmp_path_factory, run_command) -> zipfile.ZipFile:
    """The wheel pip builds from a copy of the checkout: setuptools builds in the source's ``build/``, which
    two test workers building at once (or a build left there) would share."""
    out = tmp_path_factory.mktemp("wheel")
    source = out / "source"
    ignore = shutil.ignore_patterns(*SKIP - {"tests", "bench", "docs"}, "*.egg-info", "__pycache__", ".*_cache")
    shutil.copytree(ROOT, source, ignore=ignore, symlinks=True)
    result = run_command(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(source)],
        "pip wheel",
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    (path,) = out.glob("hapticlab-*.whl")
    return zipfile.ZipFile(path)


def test_every_package_folder_is_in_the_wheel(wheel):
    names = set(wheel.namelist())
    for package in sorted(package_folders()):
        init = package.replace(".", "/") + "/__init__.py"
        assert init in names, f"{package} is missing from the wheel (add it to [tool.setuptools] packages)"


def test_presets_and_typing_marker_ship(wheel):
    names = set(wheel.namelist())
    assert "hapticlab/sessions/presets/demo.toml" in names
    assert "hapticlab/py.typed" in names


def test_console_script_is_declared(wheel):
    entry_points = next(n for n in wheel.namelist() if n.endswith("entry_points.txt"))
    assert "hapticlab = hapticlab.sessions.cli:main" in wheel.read(entry_points).decode()
