"""Compiled (numba) per-sample kernels of the estimators (issue 12).

One kernel per module, each the compiled twin of a numpy reference that stays
callable (the estimators' ``kernel = "numpy"``) and that the tests compare it to:

* ``rls``: the paper's Algorithm 1 cascade in information form (``plugins.estimators.rls.information_form``);
* ``kalman``: the drift Kalman stage, x = [a, b] (``plugins.estimators.kalman.stage._filter6``), and
  the whole force→torque cascade of the ``kalman`` estimator's default model;
* ``tilt_walk``: the intensity of the ``kalman`` biases' walk with the tool's tilt,
  learnt from the data in the cascade's loop (the reference runs the same function
  as Python, ``learn_tilt_walk.py_func``);
* ``inertia``: the motion derivatives (``plugins.estimators.kalman.derivatives``) and the inertial
  force of the ``kalman`` estimator's ``inertia`` option;
* ``align``: the live aligner's per-block work (``core.aligner``);
* ``servo``: the simulated servoed robot's state at the times a live
  simulation asks for, one sample at a time (``plugins/simworld/servo.py``);
* ``pose``: the quaternion a live simulated robot reports, encoder jitter included
  (``plugins/kinematics/sim.py``).

Compiled with ``cache=True`` (the machine code is kept in ``__pycache__``);
each module's ``warm_up()`` compiles or loads it before the first live tick. numba checks a cached
function against its own source file only: after editing a function another module's
kernel calls (``kalman_stage`` or ``tilt_walk`` from the ``kalman`` cascade), delete the
``__pycache__/*.nbi`` and ``*.nbc`` files, or the caller runs the old code.
"""

KERNELS = ("numba", "numpy")
"""The values of the estimators' ``kernel`` option."""


def kernel_option(value) -> str:
    """A ``kernel`` option: "numba" (compiled, the default) or "numpy" (the reference); ValueError naming the key."""
    if value not in KERNELS:
        raise ValueError(f"kernel: must be 'numba' (compiled) or 'numpy' (the reference), got {value!r}")
    return value
