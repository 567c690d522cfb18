"""The data screen: which of a block's samples may reach the estimators, and what was wrong with the others.

A sample is usable when its orientation is not stale, its status is good, its wrench and pose are finite
(``AlignedSamples.usable``) and its reading lies within the sensor's range (:func:`implausible`: a good
status beyond the range is impossible, the sensor would have saturated). :func:`screen` does all of it in
one compiled pass (``gate_kernel``); :func:`implausible` and :func:`data_reason` are its reference.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.host.interfaces import HasRange
from hapticlab.core.types import STATUS_OK, AlignedSamples
from hapticlab.sessions.live import gate_kernel as screen_kernel


def implausible(block: AlignedSamples, sensor: HasRange | None) -> np.ndarray:
    """(N,) True where a reading with a good status lies beyond the sensor's range (impossible: it saturates)."""
    if sensor is None:
        return np.zeros(len(block), dtype=bool)
    with np.errstate(invalid="ignore"):
        beyond = (np.abs(block.force_S) > sensor.range_force_S).any(1) | (
            np.abs(block.torque_S) > sensor.range_torque_S
        ).any(1)
    return beyond & (block.status == STATUS_OK)


BEYOND_RANGE = "implausible sensor reading (beyond its range)"
STALE = "stale kinematics"
BAD_STATUS = "sensor saturated or in error"
NON_FINITE = "non-finite sensor reading"


def data_reason(block: AlignedSamples, usable: np.ndarray, beyond: np.ndarray) -> str:
    """What was wrong with a block of aligned samples ("" when every sample is usable)."""
    if usable.all():
        return ""
    if beyond.any():
        return BEYOND_RANGE
    if block.stale.any():
        return STALE
    if (block.status != STATUS_OK).any():
        return BAD_STATUS
    return NON_FINITE


_NO_RANGE = np.empty(0)
_NO_POSITION = np.empty((0, 3))
_REASONS = (
    (screen_kernel.BEYOND, BEYOND_RANGE),
    (screen_kernel.STALE, STALE),
    (screen_kernel.BAD_STATUS, BAD_STATUS),
    (screen_kernel.NON_FINITE, NON_FINITE),
)
"""The kernel's bits and their reasons, in :func:`data_reason`'s order."""


def screen(block: AlignedSamples, sensor: HasRange | None) -> tuple[np.ndarray, np.ndarray, str]:
    """``(usable, beyond, reason)`` for a block: ``block.usable & ~implausible(...)``, ``implausible(...)`` and
    :func:`data_reason`, in one compiled pass (``sessions.live.gate_kernel``; these three stay the reference)."""
    n = len(block)
    usable, beyond = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
    ranges: tuple[np.ndarray, np.ndarray] = (
        (_NO_RANGE, _NO_RANGE)
        if sensor is None
        else (np.asarray(sensor.range_force_S, dtype=float), np.asarray(sensor.range_torque_S, dtype=float))
    )
    bits = screen_kernel.screen_block(
        block.force_S,
        block.torque_S,
        block.R_EB,
        _NO_POSITION if block.p_BoEo_B is None else block.p_BoEo_B,
        block.stale,
        block.status,
        *ranges,
        usable,
        beyond,
    )
    reason = next((why for bit, why in _REASONS if bits & bit), "") if bits else ""
    return usable, beyond, reason
