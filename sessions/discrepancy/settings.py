"""The discrepancy workflow's knobs: the significance rule, the contact gate, the fit's sample budget, the effects."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class Settings:
    """Knobs of the workflow (defaults are the documented rule, ``docs/discrepancy.md``)."""

    folds: int = 10
    """contiguous folds of the blocked cross-validation"""
    min_gain: float = 0.01
    """a candidate must lower the held-out noise-weighted mean square by at least this share (0.01 = 1 %)"""
    min_fold_share: float = 0.8
    """and in at least this share of the folds"""
    max_sign_p: float = 0.055
    """the fold wins must also be a one-sided sign test at least this strong (8 of 10 folds: 5.5 %)"""
    min_folds: int = 5
    """short recordings get at least this many (smaller) folds: fewer cannot pass the sign test"""
    trim_share: float = 0.5
    """the robust start fits the base model on this share of the rows that fit it best"""
    warn_rms_over_noise: float = 1.5
    """a final RMS above this many times the noise estimate is warned about"""
    gate_sigmas: float = 6.0
    """the contact gate sets aside samples this many robust standard deviations (MAD) off on any channel"""
    gate_dilate_s: float = 0.25
    """and this long either side of them, s, when ``t`` is a time"""
    max_fit_samples: int = 20000
    """larger recordings are fitted and tested on every k-th sample (the RMS figures use every sample)"""
    derivative_window_s: float = 0.04
    """width of the Savitzky–Golay fits giving the motion's derivatives, s"""
    min_structure_share: float = 0.5
    """a named effect must remove at least this share of the structure (excess over the noise) the model
    leaves without it (``Discrepancy.structure_test``)"""
    contact_free: bool | None = None
    """the file is described as having no contact (None: not said); a gate that sets rows aside there is noted"""
    time_base: str = "auto"
    """what ``t`` is: "seconds", "index" (row numbers), or "auto" (index when it counts rows)"""
    effects: list[str] | None = None
    """candidate effect names (None: every registered one)"""
    effect_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    """options per effect name, e.g. {"bias_drift": {"order": 2}}"""
