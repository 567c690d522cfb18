"""The layout of the kalman cascade's state array, ``adapt``: its options and state by index.

The compiled cascade (``cascade_kernel.py``) and the numpy reference (``estimator.py`` and its parts)
keep the noise estimate's, the identified rule's, the contact judge's, the torque re-opening's and the tilt
walk's state in one float64 array, so a block crosses into compiled code in one call; these are its indices.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from hapticlab.plugins.estimators.kalman import tilt_walk_kernel
from hapticlab.plugins.estimators.kalman.options import TORQUE_PER_FORCE
from hapticlab.plugins.estimators.kalman.tilt_walk_kernel import TW_SIZE

if TYPE_CHECKING:
    from hapticlab.plugins.estimators.kalman.options import KalmanOptions

ADAPT_NOISE_F, ADAPT_NOISE_T, ADAPT_IDENTIFIED = 0, 1, 2

ADAPT_COUNT_F, ADAPT_COUNT_T, ADAPT_WINDOW, ADAPT_FORCE_SEEN = 3, 4, 5, 6

ADAPT_AUTO_F, ADAPT_AUTO_T, ADAPT_CAP_F, ADAPT_CAP_T, ADAPT_PRED_F = 7, 8, 9, 10, 11

ADAPT_REOPEN_S, ADAPT_REOPEN_LEVER, ADAPT_TQ_ONLY_S, ADAPT_TQ_ONLY_N, ADAPT_REOPENS = 14, 15, 16, 17, 18

ADAPT_REOPEN_ROW, ADAPT_PRIOR_TB, ADAPT_TQ_SUM_F, ADAPT_TQ_SUM_T = 19, 20, 23, 26

ADAPT_TORQUE_SEEN, ADAPT_CONTACT_AFTER, ADAPT_REFUSED_RUN, ADAPT_HELD_OUT, ADAPT_MOUNT = 29, 30, 31, 32, 33

ADAPT_TILT, ADAPT_GRAVITY_DIR, ADAPT_TILT_AUTO, ADAPT_TILT_TORQUE = 34, 43, 46, 47

ADAPT_GRAVITY_KNOWN, ADAPT_TILT_SPAN, ADAPT_TURN_F, ADAPT_TURN_T, ADAPT_TORQUE_EARLY, ADAPT_TW = 48, 49, 50, 51, 52, 53

ADAPT_SIZE = ADAPT_TW + TW_SIZE

CONVERGENCE_IDENTIFIED, CONVERGENCE_AT_POSE = 1.0, 2.0
"""``kalman_cascade``'s ``adapt`` array (float64), by index. Options (1.0 on): ``ADAPT_NOISE_F`` /
``ADAPT_NOISE_T`` the force / torque stage's noise estimated as it runs (``plugins.estimators.kalman.noise``),
``ADAPT_IDENTIFIED`` convergence as identified (``CONVERGENCE_IDENTIFIED``) or at the pose
(``CONVERGENCE_AT_POSE``; ``plugins.estimators.kalman.identified``), ``ADAPT_AUTO_F`` / ``ADAPT_AUTO_T``
the convergence bound from the noise estimate; ``ADAPT_REOPEN_S`` the torque-only refusal (s) after which
the torque bias is re-opened (0: never; :func:`torque_only_refusal`), ``ADAPT_REOPEN_LEVER`` the farthest a
contact can act from the sensor's origin (m), the prior variance of bias_torque_S the bias goes back to
(3 values from ``ADAPT_PRIOR_TB``, (N·m)²), ``ADAPT_CONTACT_AFTER`` how many refused samples in a row make
a contact (:func:`judge_contact`), ``ADAPT_MOUNT`` the mount rotation estimated (:func:`stage_step_mount`):
the variance of the weight under which its θ is learnt, N² (0: no mount estimate).
State, in and out: the noise estimate's weights so far (``ADAPT_COUNT_*``), its window in samples (0: not
yet known), whether the force stage has settled (its flag first up; at the pose, the identified rule's
test first passed), the bounds' caps (inf until it settles), whether the torque stage has settled
(``ADAPT_TORQUE_SEEN``, the same way: the inertial force's centre of mass waits for it), the
current torque-only refusal (s, samples, and the sums of its force and torque residuals: 3 values each from
``ADAPT_TQ_SUM_F`` / ``ADAPT_TQ_SUM_T``), the torque bias re-opened so far (count), the refused samples in a
row up to the last (``ADAPT_REFUSED_RUN``) and the samples of the refused runs that ended before they were
judged a contact (``ADAPT_HELD_OUT``), the last sample's A (9 values from ``ADAPT_TILT``, row by row,
NaN before the first) and the direction of gravity in B its tilt is measured about (3 values from
``ADAPT_GRAVITY_DIR``: B's z axis until the force stage settles, then the identified weight's, which
``ADAPT_GRAVITY_KNOWN`` says (1.0; a warm start's direction is kept); :func:`tilt_step`). With
``ADAPT_TILT_AUTO`` (1.0) the tilt walk's intensity is learnt from the data
(``plugins.estimators.kalman.tilt_walk_kernel``, its state in ``TW_SIZE`` values from ``ADAPT_TW``) and written into
qt_f after each sample, and into qt_t times ``ADAPT_TILT_TORQUE`` ((N·m/N)²; negative: qt_t is the torque's own, fixed).
``ADAPT_TILT_SPAN``: the least turn either bias follows its tilt walk over, rad (0: the plain walk;
``stage_kernel.add_tilt_noise``), and each stage's turn since it last tested a sample (``ADAPT_TURN_F``,
``ADAPT_TURN_T``, rad; state). ``ADAPT_TORQUE_EARLY`` (1.0): the torque stage sees every sample the force
stage accepts, settled or not (``torque_start = "early"``). Out: the force reading's predicted variance per
axis at the last sample (3 values from ``ADAPT_PRED_F``), the block's row of its last torque bias re-opening
(−1: none)."""


def new_state(
    options: KalmanOptions,
    *,
    noise_auto: tuple[bool, bool],
    tilt_walk_auto: bool,
    tilt_torque_follows: bool,
    prior_torque_bias_var: np.ndarray,
    mount_activate_var: float,
) -> np.ndarray:
    """A fresh ``adapt`` array for an estimator with these options: the options in, the state empty.

    The noise estimates' weights 0 and their window unknown (0 until the first time step), no stage settled,
    the auto bounds' caps inf until the force stage settles, the force reading's predicted variance and the
    last pose NaN until the first sample, tilts measured about B's z until the weight is known, the tilt
    walk's learner empty. ``noise_auto``: (force, torque) estimated as they run; ``prior_torque_bias_var``
    (3,) (N·m)², what a re-opened torque bias goes back to; ``mount_activate_var`` N², 0 without a mount
    estimate.
    """
    adapt = np.zeros(ADAPT_SIZE)
    adapt[ADAPT_NOISE_F], adapt[ADAPT_NOISE_T] = noise_auto
    adapt[ADAPT_IDENTIFIED] = {"identified": CONVERGENCE_IDENTIFIED, "pose": CONVERGENCE_AT_POSE}.get(
        options.convergence, 0.0
    )
    adapt[ADAPT_AUTO_F] = noise_auto[0] and options.converged_force_std is None
    adapt[ADAPT_AUTO_T] = noise_auto[1] and options.converged_torque_std is None
    adapt[[ADAPT_CAP_F, ADAPT_CAP_T]] = math.inf
    adapt[ADAPT_PRED_F : ADAPT_PRED_F + 3] = math.nan
    adapt[ADAPT_TILT : ADAPT_TILT + 9] = math.nan  # the last sample's pose: none yet
    adapt[ADAPT_GRAVITY_DIR : ADAPT_GRAVITY_DIR + 3] = (0.0, 0.0, 1.0)  # B's z until the weight is known
    adapt[ADAPT_TILT_AUTO] = tilt_walk_auto
    adapt[ADAPT_TILT_SPAN] = options.bias_tilt_span
    adapt[ADAPT_TORQUE_EARLY] = options.torque_start == "early"
    adapt[ADAPT_TW:] = tilt_walk_kernel.new_state()
    adapt[ADAPT_TILT_TORQUE] = TORQUE_PER_FORCE**2 if tilt_torque_follows else -1.0  # (q: variances)
    adapt[ADAPT_REOPEN_S], adapt[ADAPT_REOPEN_LEVER] = (
        float(options.torque_reopen_s),
        float(options.torque_reopen_lever),
    )
    adapt[ADAPT_PRIOR_TB : ADAPT_PRIOR_TB + 3] = prior_torque_bias_var
    adapt[ADAPT_CONTACT_AFTER] = options.contact_after
    adapt[ADAPT_MOUNT] = mount_activate_var  # the compiled cascade estimates the mount as MountStage does
    return adapt
