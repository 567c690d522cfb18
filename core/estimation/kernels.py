"""The estimators' ``kernel`` option, and how the compiled (numba) kernels are kept.

A module named ``*_kernel.py`` is compiled with numba and sits beside the numpy code it must match (the
reference, which stays callable: an estimator's ``kernel = "numpy"``); the tests compare the two. The
estimators' hot paths are compiled because a numpy call per sample costs microseconds each, and a 7 kHz
sensor leaves a tick no room for dozens of them.

Kernels compile with ``cache=True`` (the machine code is kept in ``__pycache__``); each module's
``warm_up()`` compiles or loads it before the first live tick. numba checks a cached function against its
own source file only: after editing a function another module's kernel calls (``stage_kernel`` or
``tilt_walk_kernel`` from the kalman ``cascade_kernel``), delete the ``__pycache__/*.nbi`` and ``*.nbc``
files, or the caller runs the old code.
"""

KERNELS = ("numba", "numpy")
"""The values of the estimators' ``kernel`` option."""


def kernel_option(value: object) -> str:
    """A ``kernel`` option: "numba" (compiled, the default) or "numpy" (the reference); ValueError naming the key."""
    if not isinstance(value, str) or value not in KERNELS:
        raise ValueError(f"kernel: must be 'numba' (compiled) or 'numpy' (the reference), got {value!r}")
    return value
