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
_pools: dict[int, ThreadPoolExecutor] = {}
"""One pool per thread count asked for, kept for the process's life (never shut down under a caller)."""
_default: int | None = None
_override: contextvars.ContextVar[int | None] = contextvars.ContextVar("hapticlab_threads", default=None)


def _forget_pools() -> None:
    """In a forked child: the parent's pools are there but their threads are not (a map would wait forever)."""
    global _lock, _pools
    _lock, _pools = threading.Lock(), {}


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


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
    """How many threads :func:`thread_map` uses here (:func:`workers`' count, else the default)."""
    global _default
    override = _override.get()
    if override is not None:
        return override
    if _default is None:
        _default = _default_count()
    return _default


@contextmanager
def workers(count: int) -> Iterator[None]:
    """Use ``count`` threads (1: none) inside the ``with`` block, in this thread (and what it runs in the
    pool) only: a context variable, so two threads may each ask for their own."""
    token = _override.set(max(1, min(MAX_WORKERS, int(count))))
    try:
        yield
    finally:
        _override.reset(token)


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


def _share_arenas() -> None:
    """Let the pools' threads share one glibc malloc arena (the process: two at most).

    By default glibc gives each thread its own arena, which keeps the blocks
    freed in it: the workers' block-sized temporaries then raised the peak of
    ``discrepancy`` on 600 000 rows by 50 MiB (927 → 876 MiB with two arenas,
    at the same speed, on 2 cores; the tasks allocate a few arrays each, so
    sharing a lock costs little). Does nothing off glibc, or when the user
    set the arenas (``MALLOC_ARENA_MAX``, ``GLIBC_TUNABLES``' ``arena_max``).
    """
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return
    if "MALLOC_ARENA_MAX" in os.environ or "arena_max" in os.environ.get("GLIBC_TUNABLES", ""):
        return
    try:
        libc = ctypes.CDLL(None)
        libc.mallopt(ctypes.c_int(M_ARENA_MAX), ctypes.c_int(2))
    except (OSError, AttributeError):  # no mallopt in this process's C library: nothing to tune
        return


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, the calls spread over the pool's threads (in order; an exception raised
    by one is raised here). In line when there is one thread, one item, or when called from a worker."""
    tasks = list(items)
    count = worker_count()
    if count == 1 or len(tasks) < 2 or getattr(_inside, "active", False):
        return [fn(x) for x in tasks]
    with _lock:
        pool = _pools.get(count)
        if pool is None:
            _share_arenas()
            pool = _pools[count] = ThreadPoolExecutor(count, thread_name_prefix="hapticlab-numpy")
    return list(pool.map(_in_context(fn), tasks))


def column_median(x: np.ndarray) -> np.ndarray:
    """(k,) ``np.median(x, axis=0)`` of ``x`` (n, k), each column in its own task (the same numbers: the
    median of a column is the same selection whichever way it is laid out)."""
    columns = np.ascontiguousarray(np.asarray(x, float).T)
    return np.array(thread_map(np.median, columns), dtype=float).reshape(x.shape[1:])
