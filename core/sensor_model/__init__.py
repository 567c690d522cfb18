"""The sensor model along a recorded motion (the discrepancy workflow's), and what an effect plugin writes against.

``motion.py`` the recorded motion and its derivatives, ``effect.py`` the effect
interface and the measurement chain's stages, ``model.py`` the base model plus
effects as one parameter vector, ``play_kernel.py`` the compiled play operator
(hysteresis). An effect plugin imports what it needs from here::

    from hapticlab.core.sensor_model import Effect, ModelState, Motion
"""

from hapticlab.core.sensor_model.effect import STAGES, Effect, LocatesItself, ModelState
from hapticlab.core.sensor_model.model import BASE_LABELS, Model
from hapticlab.core.sensor_model.motion import Motion, motion_from_poses

__all__ = ["BASE_LABELS", "STAGES", "Effect", "LocatesItself", "Model", "ModelState", "Motion", "motion_from_poses"]
