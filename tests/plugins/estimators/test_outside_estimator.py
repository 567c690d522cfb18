"""An estimator from an outside package, installed with its entry point, runs as the primary.

The package gives only the contract's minimum (``update_block``: no ``params()``, no ``cov_diag()``, no
std): it takes the mean of the first samples as the sensor's bias, which is right for a tool that does not
turn, and says nothing of the tool's weight. The host must record it, review it and compensate with it
without a traceback, and keep the haptic force off with a reason that names what is missing: without
``gravity_force_B`` and ``bias_force_S`` it cannot check that the robot's poses are in step with the wrench.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

import hapticlab

PACKAGE = '''
"""mean_bias: the mean of the first samples is the bias; everything after it is contact."""

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.types import Estimates

WARM_UP = 200
"""Samples averaged into the bias before the estimate counts as converged."""


class MeanBias:
    """The contract's minimum: update_block only."""

    def __init__(self, warm_up: int = WARM_UP):
        self.warm_up = warm_up
        self.sums = np.zeros(6)
        self.n = 0

    def update_block(self, block):
        wrench = np.hstack([block.force_S, block.torque_S])
        out = np.empty_like(wrench)
        converged = np.empty(len(wrench), dtype=bool)
        for k, row in enumerate(wrench):
            if self.n < self.warm_up:
                self.sums += row
                self.n += 1
            out[k] = row - self.sums / self.n
            converged[k] = self.n >= self.warm_up
        contact = np.linalg.norm(out[:, :3], axis=1) > 1.0
        return Estimates(block.t_ns, out[:, :3], out[:, 3:], contact, converged, converged.copy())


@hookimpl
def register_estimators(register):
    register("mean_bias", MeanBias)
'''

PYPROJECT = """
[build-system]
requires = ["setuptools"]
build-backend = "setuptools.build_meta"

[project]
name = "outside-estimator"
version = "0.1"

[project.entry-points.hapticlab]
outside = "outside_estimator"
"""


def install_outside_package(tmp_path: Path, run_command) -> dict[str, str]:
    """Build and install the outside package into a folder of its own; the environment that sees it."""
    source = tmp_path / "src"
    (source / "outside_estimator").mkdir(parents=True)
    (source / "outside_estimator" / "__init__.py").write_text(textwrap.dedent(PACKAGE))
    (source / "pyproject.toml").write_text(PYPROJECT)
    site = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target", str(site)]
    built = run_command([*pip, str(source)], "pip install of the outside package")
    assert built.returncode == 0, built.stderr
    env = dict(os.environ, PYTHONPATH=str(site))
    env["HAPTICLAB_LOAD_PLUGINS"] = "outside"  # the entry point's name: the suite loads none by default
    return env


def hapticlab_cli(run_command, args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    """``hapticlab ARGS`` in a fresh interpreter that sees the installed package."""
    command = Path(sys.executable).with_name("hapticlab")  # the console script the venv installed
    return run_command([str(command), *args], f"hapticlab {args[0]}", timeout=600, env=env, cwd=cwd)


def test_an_outside_estimator_with_only_the_minimum_runs_as_the_primary(tmp_path, run_command):
    env = install_outside_package(tmp_path, run_command)
    listed = hapticlab_cli(run_command, ["plugins"], env, tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert "mean_bias" in listed.stdout and "outside-estimator 0.1" in listed.stdout

    rec_path = tmp_path / "outside.mcap"
    run = hapticlab_cli(
        run_command,
        [
            "run",
            "--duration",
            "3",
            "--out",
            str(rec_path),
            "--set",
            "session.realtime=false",
            "--set",
            "estimator.name=mean_bias",
        ],
        env,
        tmp_path,
    )
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr

    rec = hapticlab.open_recording(rec_path)
    assert rec.meta("hapticlab.summary", "error") == ""
    assert rec.meta("hapticlab.summary", "params") == {}  # it reports none: the summary says so, no failure
    estimates = rec.estimates("mean_bias")
    assert len(estimates.contact_force_S) == len(rec.wrench()[1]) > 1000
    assert estimates.converged_force[-1]
    # the force stays off, the whole session, for the reason the estimator's contract leaves the host
    commands = [m for _, m in rec.messages("/haptic/command")]
    assert not any(m["enabled"] for m in commands)
    reasons = {m["reason"] for m in commands[len(commands) // 2 : -1]}  # (the last: the session's end)
    assert reasons == {
        "mean_bias reports no weight model (gravity_force_B and bias_force_S): the poses cannot be checked"
    }, reasons
    assert any(e.kind == "fault" and "reports no weight model" in e.message for e in rec.events)

    review = hapticlab_cli(run_command, ["review", str(rec_path)], env, tmp_path)
    assert review.returncode == 0, review.stderr

    params_out = tmp_path / "params.json"
    compensated = hapticlab_cli(
        run_command,
        [
            "compensate",
            str(rec_path),
            "-o",
            str(tmp_path / "contact.csv"),
            "--estimator",
            "mean_bias",
            "--params-out",
            str(params_out),
        ],
        env,
        tmp_path,
    )
    assert compensated.returncode == 0, compensated.stderr
    assert json.loads(params_out.read_text()).get("gravity_force_B") is None
    rows = np.loadtxt(tmp_path / "contact.csv", delimiter=",", skiprows=1)
    assert len(rows) == len(estimates.contact_force_S)
