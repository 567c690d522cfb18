"""Independent numpy work on every core: a shared thread pool for the offline workflows.

numpy releases the GIL inside its loops, so independent predictions (a
finite-difference Jacobian's columns, a long recording's row blocks) and
per-column medians run side by side in threads, with the same numbers as one
after another: each task writes only its own result, in its own place.
The live loop never uses this: a tick is one sample, and threads would only
add jitter to it.

``HAPTICLAB_THREADS`` sets how many (default: the cores this process may use,
at most :data:`MAX_WORKERS`; ``1`` runs everything in the calling thread).
:func:`workers` changes it for a block of code (the tests compare both).
"""

from __future__ import annotations

import contextvars
import ctypes
import os
import platform
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

import numpy as np

from hapticlab.core.errors import ConfigError

__all__ = ["MAX_WORKERS", "column_median", "thread_map", "worker_count", "workers"]

T = TypeVar("T")
R = TypeVar("R")

MAX_WORKERS = 8
"""At most this many threads (beyond a few, the workflows' tasks are too short to share)."""

_lock = threading.Lock()
_inside = threading.local()
_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_count: int | None = None


def _default_count() -> int:
    """``HAPTICLAB_THREADS``, else the cores this process may run on (at most :data:`MAX_WORKERS`)."""
    text = os.environ.get("HAPTICLAB_THREADS", "").strip()
    if text:
        try:
            return max(1, min(MAX_WORKERS, int(text)))
        except ValueError:
            raise ConfigError(f"HAPTICLAB_THREADS={text!r}: expected a whole number of threads") from None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(MAX_WORKERS, cores))


def worker_count() -> int:
    """How many threads :func:`thread_map` uses now."""
    global _count
    if _count is None:
        _count = _default_count()
    return _count


@contextmanager
def workers(count: int) -> Iterator[None]:
    """Use ``count`` threads (1: none) inside the ``with`` block."""
    global _count
    before = worker_count()
    _count = max(1, min(MAX_WORKERS, int(count)))
    try:
        yield
    finally:
        _count = before


def _in_context(fn: Callable[[T], R]) -> Callable[[T], R]:
    """``fn`` run in a copy of the caller's context (numpy's error state, ``np.errstate``, is a context
    variable: a block that ignores overflow ignores it in its tasks too), its thread marked as a worker while
    it runs (so a map inside it runs in line instead of waiting for a busy pool)."""
    context = contextvars.copy_context()

    def run(item: T) -> R:
        _inside.active = True
        try:
            return context.copy().run(fn, item)
        finally:
            _inside.active = False

    return run


M_ARENA_MAX = -8
"""glibc's ``mallopt`` parameter for the number of malloc arenas (``malloc.h``)."""


def _share_arenas(count: int) -> None:
    """Let the pool's threads share one glibc malloc arena (the process: two at most).

    By default glibc gives each thread its own arena, which keeps the blocks
    freed in it: the workers' block-sized temporaries then raised the peak of
    ``discrepancy`` on 600 000 rows by 50 MB (949 → 897 MB with two arenas, at
    the same speed). Does nothing off glibc.
    """
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return
    try:
        libc = ctypes.CDLL(None)
        libc.mallopt(ctypes.c_int(M_ARENA_MAX), ctypes.c_int(2 if count > 1 else 1))
    except (OSError, AttributeError):  # no mallopt in this process's C library: nothing to tune
        return


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, the calls spread over the pool's threads (in order; an exception raised
    by one is raised here). In line when there is one thread, one item, or when called from a worker."""
    tasks = list(items)
    count = worker_count()
    if count == 1 or len(tasks) < 2 or getattr(_inside, "active", False):
        return [fn(x) for x in tasks]
    global _pool, _pool_size
    with _lock:
        if _pool is None or _pool_size != count:
            if _pool is not None:
                _pool.shutdown(wait=False)
            _share_arenas(count)
            _pool, _pool_size = ThreadPoolExecutor(count, thread_name_prefix="hapticlab-numpy"), count
        pool = _pool
    return list(pool.map(_in_context(fn), tasks))


def column_median(x: np.ndarray) -> np.ndarray:
    """(k,) ``np.median(x, axis=0)`` of ``x`` (n, k), each column in its own task (the same numbers: the
    median of a column is the same selection whichever way it is laid out)."""
    columns = np.ascontiguousarray(np.asarray(x, float).T)
    return np.array(thread_map(np.median, columns), dtype=float).reshape(x.shape[1:])
