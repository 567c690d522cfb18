"""``gain_crosstalk``: the symmetric part of the sensor's calibration error.

The sensor reads ``(I + G_f) f`` and ``(I + G_t) τ`` for a true force f and
torque τ, before its bias. A general 3x3 calibration error splits into a
uniform scale, an antisymmetric part and a symmetric traceless part:

* a uniform scale of the force is absorbed by the tool's weight
  (``gravity_force_B``), of the torque by the centre of mass: not identifiable,
  left out;
* the antisymmetric part of the force's is a small rotation of the force
  axes, which is ``mount_rotation``; the antisymmetric part of the
  *torque's* is not a mount rotation (that would turn the force too) and is
  not modelled: a torque-only antisymmetric error is named ``gain_crosstalk``,
  whose symmetric terms take the part of it they can (``docs/discrepancy.md``);
* what remains, and is modelled here, is symmetric and traceless: per-axis
  scale differences and symmetric cross-axis coupling, 5 parameters each
  (gxx, gyy, gxy, gxz, gyz; gzz = −gxx − gyy) for the force and the torque.

One torque direction stays unidentifiable from gravity alone:
``G_t ∝ c cᵀ − |c|²/3 I`` (c the centre of mass) changes nothing that a
longer or shorter c does not; the workflow's least squares leaves such
directions at zero (minimum norm).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.sensor_model import Effect, ModelState


def gain_matrix(p: np.ndarray) -> np.ndarray:
    """The symmetric traceless 3x3 matrix of (gxx, gyy, gxy, gxz, gyz)."""
    xx, yy, xy, xz, yz = p
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, -xx - yy]])


class GainCrosstalk(Effect):
    """Symmetric traceless calibration errors G_f (force) and G_t (torque), dimensionless."""

    stage = "sensor"
    labels = tuple(f"{kind}_{c}" for kind in ("force", "torque") for c in ("gxx", "gyy", "gxy", "gxz", "gyz"))
    steps = (1e-5,) * 10
    description = "sensor calibration error: per-axis gain and symmetric crosstalk"

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        I3 = np.eye(3)
        return state.replace(
            force_S=state.force_S @ (I3 + gain_matrix(params[:5])).T,
            torque_S=state.torque_S @ (I3 + gain_matrix(params[5:])).T,
        )

    def describe(self, params: np.ndarray) -> dict:
        return {"gain_force_S": gain_matrix(params[:5]).tolist(), "gain_torque_S": gain_matrix(params[5:]).tolist()}

    def summary(self, params: np.ndarray) -> str:
        f, t = gain_matrix(params[:5]), gain_matrix(params[5:])
        return (
            f"force diag [{', '.join(f'{100 * v:.2f}' for v in np.diag(f))}] %, largest coupling "
            f"{100 * np.abs(f - np.diag(np.diag(f))).max():.2f} %; torque diag "
            f"[{', '.join(f'{100 * v:.2f}' for v in np.diag(t))}] %"
        )

    def estimator_options(self, params: np.ndarray) -> dict:
        return self.describe(params)


@hookimpl
def register_effects(register):
    """Register ``gain_crosstalk``."""
    register("gain_crosstalk", GainCrosstalk)
