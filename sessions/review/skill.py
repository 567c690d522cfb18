"""Force-based skill metrics of a teleoperated task, each from the recording alone (keys: ``skill_names.py``).

The set is the one surgical-skill research uses to grade force in minimally invasive and robotic surgery:

* **peak force** and the **force–time integral** (∫‖F‖ dt over the contact), with **time in contact**,
  **path length** and **task time**: Trejos, Patel, Malthaner, Schlachta, "Development of force-based
  metrics for skills assessment in minimally invasive surgery", Surg. Endosc. 28 (2014) 2106–2119;
* the **force derivative** (how fast the force changes: mean and max of |dF/dt|), ibid.;
* **excessive-force events**, runs above the task's force limit (count, total time): Golahmadi, Khan, Mylonas,
  Marcus, "Tool–tissue forces in surgery: a systematic review", Ann. Med. Surg. 65 (2021) 102268, where
  novices' forces run above experts' by a factor (the "novice/expert force ratio");
* **SPARC**, the spectral arc length of the force profile (0 smoothest, more negative: more sub-movements):
  Balasubramanian, Melendez-Calderon, Roby-Brami, Burdet, "On the analysis of movement smoothness",
  J. NeuroEng. Rehabil. 12 (2015) 112, applied to tool–tissue force as in Singh et al., 2024.

Every function takes plain arrays (times in s, forces in N, positions in m) so a test can hand it a profile it
computed by hand; ``skill_fold.py`` gathers them from a recording, streaming.
"""

from __future__ import annotations

import math

import numpy as np

SPARC_CUTOFF_HZ = 10.0
"""Highest frequency SPARC looks at, Hz (Balasubramanian 2015's default: human movement lies below 10 Hz)."""
SPARC_AMPLITUDE = 0.05
"""SPARC's adaptive cut-off: the spectrum is read up to where it last exceeds this share of its peak (ibid.)."""
SPARC_PADDING = 4
"""Zero padding of SPARC's FFT, in powers of two beyond the signal's length (ibid.'s default)."""
RATE_SMOOTHING_S = 0.05
"""The force derivative is taken on the force's 50 ms running mean: a 1 kHz sensor's 0.1 N noise
differentiated sample to sample reads ~100 N/s, more than any hand makes (a firm press is ~10 N/s)."""


def peak_force(force: np.ndarray) -> float:
    """The largest tool–tissue force, N, of ``force`` (N,) magnitudes in N; NaN for none."""
    force = np.asarray(force, dtype=float)
    return float(np.nanmax(force)) if force.size and np.isfinite(force).any() else math.nan


def force_time_integral(force: np.ndarray, period_s: float) -> float:
    """∫‖F‖ dt, N·s, of force magnitudes (N,) in N sampled every ``period_s`` s (the samples in contact:
    Trejos et al. 2014's "force–time integral", a rectangle rule as each sample holds for one period)."""
    force = np.asarray(force, dtype=float)
    return float(np.nansum(force) * period_s)


def force_rate(force: np.ndarray, period_s: float) -> tuple[float, float]:
    """(mean |dF/dt|, max |dF/dt|), N/s, of a contact's force magnitudes (N,) in N every ``period_s`` s,
    on its :data:`RATE_SMOOTHING_S` running mean (central differences); (NaN, NaN) when too short."""
    force = np.asarray(force, dtype=float)
    width = max(1, round(RATE_SMOOTHING_S / period_s))
    if len(force) < width + 2:
        return math.nan, math.nan
    smooth = np.convolve(force, np.full(width, 1.0 / width), mode="valid")
    rate = np.abs(np.gradient(smooth, period_s))
    return float(rate.mean()), float(rate.max())


def sparc(profile: np.ndarray, rate_hz: float) -> float:
    """The spectral arc length of ``profile`` (N,) sampled at ``rate_hz`` Hz, dimensionless (≤ 0).

    The profile's Fourier magnitude, normalised to its peak, is read from 0 Hz up to the last frequency below
    :data:`SPARC_CUTOFF_HZ` where it still exceeds :data:`SPARC_AMPLITUDE`; SPARC is minus the arc length of
    that curve with the frequency axis normalised to the band (Balasubramanian et al. 2015, eq. 4–6). It
    does not depend on the profile's amplitude or duration; a single smooth bump reads about −1.4, a
    profile of several bumps reads lower. NaN for fewer than 3 samples or a zero profile.
    """
    profile = np.asarray(profile, dtype=float)
    if len(profile) < 3 or not np.isfinite(profile).all() or not np.any(profile):
        return math.nan
    n = 2 ** int(math.ceil(math.log2(len(profile))) + SPARC_PADDING)
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    M = np.abs(np.fft.rfft(profile, n))
    M = M / M.max()
    band = f <= SPARC_CUTOFF_HZ
    f, M = f[band], M[band]
    above = np.flatnonzero(M >= SPARC_AMPLITUDE)
    f, M = f[above[0] : above[-1] + 1], M[above[0] : above[-1] + 1]
    if len(f) < 2:
        return math.nan
    df = np.diff(f) / (f[-1] - f[0])
    return float(-np.sum(np.sqrt(df**2 + np.diff(M) ** 2)))


def excess_force_events(t_s: np.ndarray, force: np.ndarray, limit_N: float, merge_gap_s: float) -> list[tuple]:
    """The runs of ``force`` (N,) N above ``limit_N`` at times ``t_s`` (N,) s: [(start s, duration s, peak N)].

    Runs less than ``merge_gap_s`` apart are one event (a force hovering at the limit is one excursion,
    not many); a run's duration is from its first sample above to the first below (its last sample, at
    the recording's end).
    """
    t_s, force = np.asarray(t_s, dtype=float), np.asarray(force, dtype=float)
    above = force > limit_N
    if not above.any():
        return []
    edges = np.diff(np.concatenate(([0], above.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # ends: first index below
    runs: list[list] = []
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        end_t = t_s[e] if e < len(t_s) else t_s[-1]
        peak = float(force[s:e].max())
        if runs and t_s[s] - runs[-1][1] < merge_gap_s:
            runs[-1][1], runs[-1][2] = end_t, max(runs[-1][2], peak)
        else:
            runs.append([float(t_s[s]), float(end_t), peak])
    return [(start, end - start, peak) for start, end, peak in runs]


def path_length(p: np.ndarray) -> float:
    """The length of the path through the positions ``p`` (N, 3) m, m (Trejos et al. 2014's path length)."""
    p = np.asarray(p, dtype=float)
    if len(p) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
