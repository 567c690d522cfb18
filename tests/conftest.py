"""Shared fixtures, the test run's rules, and its two tiers.

Rules:

* Only the built-in plugins: ``HAPTICLAB_LOAD_PLUGINS`` is set to the empty
  string before any registry is built, so a third-party hapticlab plugin
  installed in the same environment cannot change what the tests see.
* Under ``CI=true`` the real recordings (``../shared/data/real``) must be
  there: a test that needs them fails instead of skipping.
* numba's on-disk cache has one folder per pytest-xdist worker
  (``.pytest_cache/numba/<worker>``; ``gw0`` for a run without workers):
  numba reads a function's cache index, adds an entry and writes it back
  without a lock, so two processes compiling two signatures of one function
  at once could leave an entry naming the other one's machine code.

Tiers. A test is marked from the fixtures it takes (``REALTIME`` and ``SLOW``
below), never by hand:

* ``realtime``: the test depends on the wall clock or on another party
  keeping pace (a paced session, a process beside the test, a pseudo-terminal,
  Dask worker processes). It runs alone and serially:
  ``pytest -m realtime -n 0``.
* ``slow``: expensive by nature (the real recordings, the numpy references the
  compiled kernels are held to, whole benchmark runs, simulated sessions
  longer than ``LONG_SESSION_S``).

The default run (``pytest``, pyproject's ``addopts``) leaves both out;
``pytest -m "not realtime"`` adds the slow tier (CI runs it, then the realtime
tier). A test that takes one of these resources any other way fails, naming
the fixture to take it through (the tier guard, ``pytest_configure``), so the marks
cannot drift.
Every realtime resource waits with a timeout of its own that names what it
waited for, and pytest-timeout (``REALTIME_TIMEOUT_S``, pyproject's
``timeout`` for the rest) ends a test stuck anywhere else; its report then
says which resources the test was waiting on.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

os.environ["HAPTICLAB_LOAD_PLUGINS"] = ""  # built-ins only (entry points: none)
os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    str(Path(__file__).resolve().parents[1] / ".pytest_cache" / "numba" / os.environ.get("PYTEST_XDIST_WORKER", "gw0")),
)  # before numba is imported (below, through hapticlab)

import pytest
from helpers import REAL_DATA
from processes import Child, start_child

REALTIME = {
    "paced_run": "a paced session (session.realtime = true)",
    "spawn_process": "a process beside the test",
    "pty_pair": "a pseudo-terminal pair",
    "master_emulator": "the master emulator on a pseudo-terminal",
    "ft300_emulator": "the Robotiq FT 300 emulator on a pseudo-terminal, streaming at 100 Hz",
    "netft_emulator": "the Net F/T emulator streaming RDT over UDP at its own rate",
    "bota_emulator": "the Bota serial sensor emulator on a pseudo-terminal, streaming at its own rate",
    "dask_workers": "Dask worker processes",
    "child_processes": "processes the code under test starts",
}
"""Fixture → the resource it gives a test; a test that takes one is marked ``realtime``."""
SLOW = {
    "real_data": "the real recordings",
    "numpy_reference": "the numpy reference kernels, sample by sample",
    "bench_run": "a whole benchmark run",
    "long_session": "a simulated session longer than LONG_SESSION_S",
    "run_command": "a command in a fresh interpreter",
}
"""Fixture → what makes a test that takes it expensive; such a test is marked ``slow``, and so is one
parametrized with an estimator's reference (``_runs_a_reference``)."""
REALTIME_TIMEOUT_S = 240
"""s: a realtime test's whole time (its sessions are at most 30 s; the rest is start-up on a loaded machine)."""
LONG_SESSION_S = 10.0
"""s: a simulated (not paced) session longer than this is taken through ``long_session`` (the slow tier)."""


# --------------------------------------------------------------------------- marks


@pytest.hookimpl(tryfirst=True)  # before -m deselects by mark
def pytest_collection_modifyitems(config, items):
    for item in items:
        used = set(getattr(item, "fixturenames", ()))
        params = getattr(getattr(item, "callspec", None), "params", {})
        if used & REALTIME.keys():
            item.add_marker(pytest.mark.realtime)
            if item.get_closest_marker("timeout") is None:
                item.add_marker(pytest.mark.timeout(REALTIME_TIMEOUT_S))
        if used & SLOW.keys() or _runs_a_reference(params):
            item.add_marker(pytest.mark.slow)


def _runs_a_reference(params: dict) -> bool:
    """A test parametrized with an estimator's reference: ``kernel="numpy"``, or options holding
    ``{"kernel": "numpy"}`` or ``{"implementation": "filterpy"}``."""
    for name, value in params.items():
        if name == "kernel" and value == "numpy":
            return True
        if isinstance(value, dict) and (value.get("kernel") == "numpy" or value.get("implementation") == "filterpy"):
            return True
    return False


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A test that pytest-timeout ended says which resources it was waiting on."""
    outcome = yield
    report = outcome.get_result()
    if report.failed and "from pytest-timeout" in str(report.longrepr):
        used = [f"{REALTIME[name]} ({name})" for name in REALTIME if name in getattr(item, "fixturenames", ())]
        report.sections.append(
            ("waiting on", "; ".join(used) if used else "nothing a fixture gave it: its own computation or a hang")
        )


# --------------------------------------------------------------------------- the tier guard

TESTS = Path(__file__).resolve().parent
_ALLOWED_SPAWNERS = ("hapticlab.sessions.recording.process_sink", "hapticlab.sessions.recording.metadata")
"""Modules whose processes every session starts (the recording's writer process, ``git rev-parse`` for the metadata):
allowed anywhere."""
_current: list = [None]
"""The test being set up, run or torn down (its module fixtures included); None between tests."""


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current[0] = item
    try:
        yield
    finally:
        _current[0] = None


def _outside(tier: str) -> bool:
    item = _current[0]
    return item is not None and item.get_closest_marker(tier) is None


def _tier_fail(what: str, fixture: str, tier: str) -> None:
    pytest.fail(
        f"this test {what} outside the {tier} tier: take it through the `{fixture}` fixture (tests/conftest.py)"
    )


def _spawner() -> tuple[str, str]:
    """(module, file) that asked ``subprocess`` for a process: the first frame outside ``subprocess``."""
    frame = sys._getframe(2)
    while frame is not None and frame.f_globals.get("__name__") == "subprocess":
        frame = frame.f_back
    return ("", "") if frame is None else (frame.f_globals.get("__name__", ""), frame.f_code.co_filename)


def pytest_configure(config):
    """The tier guard, for the whole run: outside the realtime tier no paced session, pty, process started by a
    test or by hapticlab (a recording's writer aside) or Dask cluster; outside the slow tier no simulated
    session longer than ``LONG_SESSION_S``. Each names the fixture that gives a test the resource."""
    from hapticlab.sessions.live import loop

    run = loop.LiveLoop.run

    def guarded_run(self):
        if self.s.settings.realtime and _outside("realtime"):
            _tier_fail("runs a paced session (session.realtime = true)", "paced_run", "realtime")
        if not self.s.settings.realtime and self.duration > LONG_SESSION_S and _outside("slow"):
            _tier_fail(f"runs a {self.duration:g} s simulated session", "long_session", "slow")
        return run(self)

    loop.LiveLoop.run = guarded_run
    openpty = os.openpty

    def guarded_openpty():
        if _outside("realtime"):
            _tier_fail("opens a pseudo-terminal", "pty_pair`, `master_emulator` or `bota_emulator", "realtime")
        return openpty()

    os.openpty = guarded_openpty
    popen_init = subprocess.Popen.__init__

    def guarded_popen(self, *args, **kwargs):
        if _outside("realtime"):
            module, filename = _spawner()
            by_test = Path(filename).resolve().is_relative_to(TESTS)
            by_hapticlab = module.startswith("hapticlab.") and not module.startswith(_ALLOWED_SPAWNERS)
            one_shot = module == __name__ and "run_command" in _current[0].fixturenames
            if (by_test or by_hapticlab) and not one_shot:
                _tier_fail(f"starts a process ({module})", "spawn_process` or `child_processes", "realtime")
        popen_init(self, *args, **kwargs)

    subprocess.Popen.__init__ = guarded_popen
    from distributed.deploy.local import LocalCluster

    cluster_init = LocalCluster.__init__

    def guarded_cluster(self, *args, **kwargs):
        if _outside("realtime"):
            _tier_fail("starts Dask worker processes", "dask_workers", "realtime")
        cluster_init(self, *args, **kwargs)

    LocalCluster.__init__ = guarded_cluster


# --------------------------------------------------------------------------- realtime resources


@pytest.fixture(scope="session")
def paced_run():
    """``run_session`` for a paced session (``session.realtime = true``): the wall clock drives its ticks, so a
    test asserts what the recording says (ticks, overrun events, stamps), never how long the wall clock took."""
    from hapticlab.sessions.live import run_session

    def run(session, out, **kwargs):
        assert session.settings.realtime, "paced_run is for paced sessions (session.realtime = true)"
        return run_session(session, out=out, **kwargs)

    return run


@pytest.fixture
def spawn_process():
    """Start a process beside the test: ``spawn_process(args, what, **popen_kwargs)`` → :class:`Child`
    (stdout and stderr piped, text, unless given). Whatever still runs at the test's end is killed."""
    started: list[Child] = []

    def spawn(args, what: str, **kwargs) -> Child:
        child = start_child(args, what, **kwargs)
        started.append(child)
        return child

    yield spawn
    for child in started:
        child.close_pipes()


@pytest.fixture
def pty_pair():
    """A pseudo-terminal pair ``(master_fd, slave_fd)``, both closed at the test's end."""
    master, slave = os.openpty()
    yield master, slave
    for fd in (master, slave):
        with contextlib.suppress(OSError):  # closed by the test
            os.close(fd)


@pytest.fixture
def master_emulator():
    """``master_emulator(*args, **kwargs)`` → a :class:`MasterEmulator` (a serial haptic master on a pty, served
    by a thread of this process); use it as a context manager. Any left serving is stopped at the test's end."""
    from hapticlab.plugins.haptics.master_emulator import MasterEmulator

    made: list[MasterEmulator] = []

    def make(*args, **kwargs) -> MasterEmulator:
        emulator = MasterEmulator(*args, **kwargs)
        made.append(emulator)
        return emulator

    yield make
    for emulator in made:
        emulator.stop()


@pytest.fixture
def ft300_emulator():
    """``ft300_emulator(world, **kwargs)`` → an :class:`FT300Emulator` (a Robotiq FT 300 on a pty, served by a thread
    of this process); use it as a context manager. Any left serving is stopped at the test's end."""
    from hapticlab.plugins.sensors.robotiq_emulator import FT300Emulator

    made: list[FT300Emulator] = []

    def make(*args, **kwargs) -> FT300Emulator:
        emulator = FT300Emulator(*args, **kwargs)
        made.append(emulator)
        return emulator

    yield make
    for emulator in made:
        emulator.stop()


@pytest.fixture
def netft_emulator():
    """``netft_emulator(*args, **kwargs)`` → a :class:`NetFTEmulator` (RDT over UDP at up to 7 kHz, served by a
    thread of this process: a receiver that falls behind loses records); use it as a context manager."""
    from hapticlab.plugins.sensors.netft_emulator import NetFTEmulator

    return NetFTEmulator


@pytest.fixture
def bota_emulator():
    """``bota_emulator(world, **kwargs)`` → a :class:`BotaEmulator` (a Bota serial sensor on a pty, served by a
    thread of this process); use it as a context manager. Any left serving is stopped at the test's end."""
    from hapticlab.plugins.sensors.bota_emulator import BotaEmulator

    made: list[BotaEmulator] = []

    def make(*args, **kwargs) -> BotaEmulator:
        emulator = BotaEmulator(*args, **kwargs)
        made.append(emulator)
        return emulator

    yield make
    for emulator in made:
        emulator.stop()


@pytest.fixture
def dask_workers() -> int:
    """How many local Dask worker processes a folder job may start (a test waits on them: realtime tier)."""
    return 2


@pytest.fixture
def child_processes():
    """The code under test starts processes of its own (e.g. ur-rtde's writer for teleoperating a UR); any
    still alive at the test's end are killed, and the test fails naming them."""
    before = set(_children())
    yield
    left = [pid for pid in _children() if pid not in before]
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
    assert not left, f"processes left running by the code under test: {left}"


def _children() -> list[int]:
    """This process's living children (from /proc)."""
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        if int(fields[1]) == os.getpid() and fields[0] != "Z":
            pids.append(int(entry))
    return pids


# --------------------------------------------------------------------------- slow resources


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The folder of real recordings; absent, tests using it skip (fail under CI=true)."""
    if not REAL_DATA.is_dir():
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{REAL_DATA} is missing: under CI=true the real-data tests must run")
        pytest.skip("../shared/data/real is not present")
    return REAL_DATA


@pytest.fixture(scope="session")
def numpy_reference() -> str:
    """The kernel name of the estimators' numpy reference (``kernel=numpy_reference``), run sample by sample in
    Python: what every compiled kernel is held to."""
    return "numpy"


@pytest.fixture(scope="session")
def bench_run():
    """``bench_run(*args)``: ``hapticlab bench ARGS`` in this process, its exit code (a whole benchmark run)."""
    from hapticlab.sessions.cli import main

    return lambda *args: main(["bench", *args])


@pytest.fixture(scope="session")
def long_session():
    """``run_session`` for a simulated session longer than ``LONG_SESSION_S`` (the slow tier)."""
    from hapticlab.sessions.live import run_session

    return run_session


@pytest.fixture(scope="session")
def run_command():
    """``run_command(args, what, timeout=300, **kwargs)``: a command that runs to its end (a fresh interpreter, a
    build) → ``subprocess.CompletedProcess`` (output captured as text); fails naming ``what`` after ``timeout``."""

    def run(args, what: str, timeout: float = 300.0, **kwargs):
        kwargs.setdefault("capture_output", True)
        kwargs.setdefault("text", True)
        try:
            return subprocess.run(args, timeout=timeout, **kwargs)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{what} did not finish within {timeout:g} s")

    return run
