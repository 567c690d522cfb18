"""The shared thread pool (``core/parallel.py``): results in order, errors raised, nested maps in line, the
count from ``HAPTICLAB_THREADS``, and per-column medians that are numpy's to the bit."""

from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest

from hapticlab.core import parallel
from hapticlab.core.errors import ConfigError
from hapticlab.core.parallel import column_median, thread_map, worker_count, workers


def test_results_come_in_the_order_of_the_items_from_the_pools_threads():
    names: set[str] = set()
    lock = threading.Lock()
    barrier = threading.Barrier(2, timeout=10)  # passes only if two calls run at once

    def square(x: int) -> int:
        with lock:
            names.add(threading.current_thread().name)
        if x < 2:
            barrier.wait()
        return x * x

    with workers(2):
        assert thread_map(square, range(20)) == [x * x for x in range(20)]
    assert len(names) == 2 and all(name.startswith("hapticlab-numpy") for name in names)


def test_one_worker_runs_in_the_calling_thread():
    with workers(1):
        assert worker_count() == 1
        assert set(thread_map(lambda _: threading.current_thread().name, range(5))) == {threading.current_thread().name}


def test_an_error_in_a_task_is_raised_to_the_caller():
    def fail_on_three(x: int) -> int:
        if x == 3:
            raise ZeroDivisionError("three")
        return x

    with workers(2), pytest.raises(ZeroDivisionError, match="three"):
        thread_map(fail_on_three, range(6))


def test_a_map_inside_a_task_runs_in_line_instead_of_waiting_for_a_busy_pool():
    def inner(x: int) -> list[int]:
        return thread_map(lambda y: x * 10 + y, range(3))

    done: list[list[list[int]]] = []
    with workers(2):
        runner = threading.Thread(target=lambda: done.append(thread_map(inner, range(4))), daemon=True)
        runner.start()
        runner.join(timeout=30)
    assert done == [[[x * 10 + y for y in range(3)] for x in range(4)]]


def test_the_count_comes_from_the_environment(monkeypatch):
    monkeypatch.setattr(parallel, "_default", None)
    monkeypatch.setenv("HAPTICLAB_THREADS", "1")
    assert worker_count() == 1
    monkeypatch.setattr(parallel, "_default", None)
    monkeypatch.setenv("HAPTICLAB_THREADS", "100")
    assert worker_count() == parallel.MAX_WORKERS
    monkeypatch.setattr(parallel, "_default", None)
    monkeypatch.setenv("HAPTICLAB_THREADS", "two")
    with pytest.raises(ConfigError, match="HAPTICLAB_THREADS='two'"):
        worker_count()


@pytest.mark.parametrize("rows", [1, 2, 7, 1000, 1001])
def test_column_median_is_numpys_median_to_the_bit(rows):
    rng = np.random.default_rng(rows)
    x = rng.standard_t(3, size=(rows, 6)) * [1e-3, 1.0, 1e3, 5.0, 0.1, 2.0]
    x[rows // 2, 4] = np.nan  # a NaN makes its column's median NaN, as numpy's
    with workers(2):
        got = column_median(x)
    want = np.median(x, axis=0)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.isnan(got[4]) and np.isfinite(np.delete(got, 4)).all()


def test_the_callers_numpy_error_state_holds_in_the_tasks():
    """``np.errstate`` is a context variable: a block that ignores overflow (``numerical_failures``) must
    ignore it in its tasks too, and one that raises on it must raise."""
    overflow = lambda x: np.float64(1e308) * x  # noqa: E731 (a one-line task)
    with workers(2), np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning from a task would fail here
        assert np.isinf(thread_map(overflow, [10.0, 20.0, 30.0])).all()
    with workers(2), np.errstate(over="raise"), pytest.raises(FloatingPointError):
        thread_map(overflow, [10.0, 20.0, 30.0])


def test_workers_is_the_calling_threads_own():
    seen: list[int] = []
    with workers(1):
        other = threading.Thread(target=lambda: seen.append(worker_count()))
        other.start()
        other.join()
        assert worker_count() == 1
    assert seen == [parallel._default_count()]


def test_a_forked_child_maps_with_pools_of_its_own():
    """The parent's pool is copied into a fork without its threads; a map there must not wait forever."""
    import multiprocessing

    with workers(2):
        thread_map(abs, [-1, -2, -3])  # the parent's pool exists
        context = multiprocessing.get_context("fork")
        with context.Pool(1) as children:
            result = children.apply_async(_map_in_child)
            assert result.get(timeout=60) == [1, 4, 9]


def _map_in_child() -> list[int]:
    with workers(2):
        return thread_map(lambda x: x * x, [1, 2, 3])
