"""Run numpy's BLAS on one thread for a while.

The workflows here multiply tall, thin matrices (a Jacobian of tens of
thousands of rows by a few dozen columns): one thread does that in a few
milliseconds, and on a 2-core machine OpenBLAS's own threads make it
erratic, many times slower at worst (and worse when scipy's separate
OpenBLAS has threads spinning too; figures in ``docs/discrepancy.md``). numpy has no
API for its thread count, so this calls OpenBLAS's through ctypes, the way
``threadpoolctl`` does; with any other BLAS it does nothing.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

_NAMES = (
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
    ("openblas_set_num_threads", "openblas_get_num_threads"),
)


@functools.cache
def _openblas() -> tuple | None:
    """(set, get) of the OpenBLAS bundled with numpy, or None."""
    folder = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for path in sorted(folder.glob("*openblas*.so*")) if folder.is_dir() else []:
        try:
            lib = ctypes.CDLL(str(path))
        except OSError:
            continue
        for set_name, get_name in _NAMES:
            setter, getter = getattr(lib, set_name, None), getattr(lib, get_name, None)
            if setter is not None and getter is not None:
                setter.argtypes, setter.restype, getter.restype = [ctypes.c_int], None, ctypes.c_int
                return setter, getter
    return None


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """numpy's OpenBLAS on one thread inside the block; the previous count restored after."""
    found = _openblas()
    if found is None:
        yield
        return
    setter, getter = found
    before = getter()
    setter(1)
    try:
        yield
    finally:
        setter(before)
