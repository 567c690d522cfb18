"""Work over folders of recordings: one task per file, in parallel with Dask.

A lab's archive is hundreds of sessions; replaying a new estimator over it,
running the discrepancy workflow over it or reviewing a cohort is one task per
recording, independent of the others. :func:`map_recordings` runs such a task
over a list of files with ``dask.distributed``:

* by default on a local cluster of worker *processes* (one thread each: the
  tasks are numpy and Python, the interpreter lock would serialise threads),
  ``workers`` of them (default: one per core), started for the job and shut
  down after it;
* with ``scheduler="tcp://HOST:PORT"`` on an existing Dask cluster (when one
  machine is not enough), whose workers must have hapticlab installed and see
  the files at the same paths.

A file the task refuses as bad input (a ``ValueError``, e.g. not a hapticlab
recording, a truncated file) becomes a row with its one-line error, and the
rest go on; anything else is a bug and raises with its traceback. A progress
bar (rich) counts files as they finish, and each worker's peak memory is
reported, so a job's size per worker is known before it goes to a cluster.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from hapticlab.core.errors import UserError

__all__ = ["FolderError", "FolderRun", "Outcome", "map_recordings", "recordings_in"]


class FolderError(UserError, ValueError):
    """A folder without recordings, a scheduler that does not answer: one line, the user's to fix."""


def recordings_in(folder: str | os.PathLike[str]) -> list[Path]:
    """The ``.mcap`` files under ``folder`` (recursively), sorted; FolderError naming the folder when none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FolderError(f"{folder}: not a folder")
    paths = sorted(p for p in folder.rglob("*.mcap") if p.is_file())
    if not paths:
        raise FolderError(f"{folder}: no .mcap recordings in it")
    return paths


@dataclass
class Outcome:
    """One file's result: ``value`` (what the task returned) or ``error`` (its one-line refusal)."""

    path: Path
    value: Any = None
    error: str = ""


@dataclass
class FolderRun:
    """What :func:`map_recordings` did: outcomes in the order of the paths, and the workers it ran on.

    Attributes:
        outcomes: one per path, in the order given.
        workers: how many worker processes ran the tasks.
        peak_rss_mb: each worker's peak resident memory, MB (by worker address).
        wall_s: the job's wall time, s (the cluster's start and stop included).
    """

    outcomes: list[Outcome]
    workers: int
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    wall_s: float = 0.0


def _run_one(func: Callable[[Path], Any], path: Path, threads: int = 1) -> tuple[Any, str]:
    """The task on a worker: (value, "") or (None, the ValueError's line), its numpy work on ``threads``
    threads (``hapticlab.core.parallel``: the worker processes already share the cores)."""
    from hapticlab.core.parallel import workers as thread_workers

    try:
        with thread_workers(threads):
            return func(path), ""
    except ValueError as exc:  # bad input (RecordingError is one): a row, not the end of the job
        return None, str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _peak_rss_mb() -> float:
    """This process's peak resident memory, MB (Linux reports ru_maxrss in KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _refused(address: str) -> None:
    """Raise ConnectionRefusedError at once when nothing listens at a ``tcp://HOST:PORT`` scheduler address
    (the client would wait out its 10 s timeout); a host that does not answer is left to the client."""
    parts = urlsplit(address)
    if parts.scheme != "tcp" or not parts.hostname or parts.port is None:
        return
    try:
        socket.create_connection((parts.hostname, parts.port), timeout=2.0).close()
    except ConnectionRefusedError:
        raise
    except OSError:  # unreachable, slow or not resolved here: the client's timeout decides
        return


def map_recordings(
    func: Callable[[Path], Any],
    paths: Sequence[str | os.PathLike[str]],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    description: str = "recordings",
) -> FolderRun:
    """Run ``func(path)`` for every path in parallel; the outcomes in the order of ``paths``.

    Args:
        func: a picklable function of one recording's path (a module-level function, or a
            ``functools.partial`` of one), run in a worker process.
        paths: the recordings.
        scheduler: an existing Dask scheduler's address ("tcp://HOST:PORT"); None: a local
            cluster of ``workers`` processes for this job.
        workers: local worker processes (default: one per core, at most one per file).
        progress: show a progress bar on stderr.
        description: what the bar counts.
    """
    import time

    from dask.distributed import Client, LocalCluster, as_completed

    files = [Path(p) for p in paths]
    start = time.perf_counter()
    cluster = None
    threads = 1  # a scheduler's workers: as many processes as it has cores, as dask's own set BLAS's threads
    if scheduler is None:
        n = workers or os.cpu_count() or 1
        n = max(1, min(n, len(files)))
        threads = max(1, (os.cpu_count() or 1) // n)  # the cores the worker processes leave each
        cluster = LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40
        )
        client = Client(cluster)
    else:
        try:
            _refused(scheduler)
            client = Client(scheduler, timeout=10)
        except (OSError, TimeoutError) as exc:
            raise FolderError(f"--scheduler {scheduler}: no Dask scheduler answered: {exc}") from None
    try:
        futures = {client.submit(_run_one, func, path, threads, pure=False): i for i, path in enumerate(files)}
        outcomes: list[Outcome | None] = [None] * len(files)
        bar = _progress(progress, description, len(files))
        with bar:
            task = bar.add_task(description, total=len(files))
            for future in as_completed(futures):
                i = futures[future]
                value, error = future.result()  # a bug in the task raises here, with its traceback
                outcomes[i] = Outcome(files[i], value, error)
                bar.advance(task)
        peaks = client.run(_peak_rss_mb)
        n_workers = len(client.scheduler_info()["workers"])
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return FolderRun([o for o in outcomes if o is not None], n_workers, peaks, time.perf_counter() - start)


def _progress(show: bool, description: str, total: int):
    """A rich progress bar on stderr (a no-op one when ``show`` is false)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        disable=not show,
        transient=False,
    )
