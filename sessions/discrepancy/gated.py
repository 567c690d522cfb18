"""What the contact gate set aside: how much, in how many stretches, and whether it rings.

The gate (``identify.Identification.gate``) sets aside rows far off the model, as contact. On a file that had
no contact that is wrong and must be said: a tool whose flexible part swings after each stop of the robot (a
long shaft, a loose clamp) is far off the model for a moment at every stop, and the gate hid 5-20 % of
simulated recordings of one with no word. :func:`set_aside` reports the share
and the stretches, and looks for ringing in them: the residual of each stretch, noise-weighted and over the six
channels, has its power at one frequency that the motion does not contain, over several periods, decaying;
then it gives the frequency and the damping ratio (from the decay of the swing's peaks). A press, a hung mass
or a touch rises and falls with the hand or the motion, at the motion's own low frequencies, and is not called
ringing.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

MIN_STRETCHES = 3
"""Ringing is looked for when the gate set aside at least this many stretches (one per stop)."""
MIN_CYCLES = 3.0
"""The peak frequency must fit at least this many periods in the median stretch."""
MIN_PEAK_SHARE = 0.4
"""The peak (± one resolution of the median stretch) holds at least this share of the stretches' power."""
MAX_MOTION_SHARE = 0.02
"""... and the motion (the model's prediction over the whole recording) at most this share of its own power
there: a frequency the motion does not contain."""
CONTACT_FREE_SHARE = 0.01
"""On a file described contact-free (``Settings.contact_free``) a gate setting aside more than this share of the
rows is noted."""


def stretches(mask: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in ``mask`` (m,), as (start, end) index pairs, end exclusive."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(), strict=True))


def _power(z: np.ndarray, nfft: int) -> np.ndarray:
    """(nfft//2 + 1,) the power spectrum of ``z`` (m, k) summed over its columns, each detrended (a line).

    A column at a time: a whole recording's six spectra at once were 160 MB (600 000 rows), the report's peak
    (the same numbers for up to 7 columns, as here: each column's transform is the 2-D call's, and below 8
    terms numpy sums in column order; from 8 its pairwise sum differs in the last bit)."""
    m = len(z)
    x = np.arange(m) - (m - 1) / 2
    mean = z.mean(axis=0)
    slope = (x @ (z - mean)) / max(float(x @ x), 1e-300)
    power = np.zeros(nfft // 2 + 1)
    for j in range(z.shape[1]):
        power += np.abs(np.fft.rfft(z[:, j] - mean[j] - x * slope[j], n=nfft)) ** 2
    return power


def _swing(u: np.ndarray, dt: float, freq: float) -> tuple[float, float] | None:
    """The frequency (Hz) and damping ratio of the swing ``u`` (m,) sampled every ``dt`` s near ``freq`` Hz: its
    half-period peaks from the largest on (where the swing starts), those above 4 of ``u``'s own noise figures;
    the frequency from the zero crossings between the first and the last of them (a spectrum's peak of a few
    decaying periods is a few % off), the damping from their decay (a line through their logarithms). None
    when there are fewer than three."""
    half = max(1, round(0.5 / (freq * dt)))
    noise = 1.4826 * float(np.median(np.abs(np.diff(u) - np.median(np.diff(u))))) / math.sqrt(2)
    start = int(np.argmax(np.abs(u))) - half // 2
    peaks = []
    for a in range(max(start, 0), len(u) - half + 1, half):
        k = a + int(np.argmax(np.abs(u[a : a + half])))
        if abs(u[k]) <= 4.0 * noise:
            break
        peaks.append(k)
    if len(peaks) < 3:
        return None
    # log-amplitudes weighted by amplitude over noise (their own scatter is noise / amplitude)
    slope = np.polyfit(np.array(peaks) * dt, np.log(np.abs(u[peaks])), 1, w=np.abs(u[peaks]) / noise)[0]
    x = u[peaks[0] : peaks[-1] + 1]
    at = np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0)
    crossings = (at + x[at] / (x[at] - x[at + 1])) * dt  # linear interpolation
    if len(crossings) >= 2:
        freq = (len(crossings) - 1) / (2.0 * float(crossings[-1] - crossings[0]))
    decay = max(-float(slope), 0.0)
    return freq, decay / math.hypot(decay, 2.0 * math.pi * freq)


def set_aside(
    t: np.ndarray, residual: np.ndarray, predicted: np.ndarray, kept: np.ndarray, noise: np.ndarray, seconds: bool
) -> dict[str, Any]:
    """The gate's share of the rows, its stretches and, when they ring, how.

    Args:
        t: (m,) the usable rows' times (s, or rows); residual, predicted: (m, 6) the final model's residual and
        prediction there (N, N·m); kept: (m,) the gate; noise: (6,) the channels' noise figures; seconds: ``t``
        is a time (no ringing is looked for in rows).

    Returns ``{"share", "rows", "stretches", "ringing"}``; ``ringing`` is None or ``{"frequency_hz",
    "damping_ratio" (None when the peaks do not say), "peak_share", "motion_share", "stretches"}``.
    """
    gated = ~kept
    runs = stretches(gated)
    out: dict[str, Any] = {
        "share": float(gated.mean()) if len(gated) else 0.0,
        "rows": int(gated.sum()),
        "stretches": len(runs),
        "ringing": None,
    }
    if not seconds or len(runs) < MIN_STRETCHES or len(t) < 2:
        return out
    dt = float(np.median(np.diff(t)))
    lengths = np.array([b - a for a, b in runs])
    nfft = 1 << math.ceil(math.log2(max(8 * lengths.max(), 4096)))
    freq = np.fft.rfftfreq(nfft, dt)
    z = residual / noise
    power = sum((_power(z[a:b], nfft) for a, b in runs if b - a >= 8), np.zeros(len(freq)))
    median_s = float(np.median(lengths)) * dt
    band = 1.0 / median_s  # the resolution of a median stretch, Hz
    usable = freq >= MIN_CYCLES / median_s
    if not usable.any() or power[1:].sum() <= 0:
        return out
    k = int(np.flatnonzero(usable)[np.argmax(power[usable])])
    near = np.abs(freq - freq[k]) <= band
    peak_share = float(power[near].sum() / power[1:].sum())
    whole = 1 << math.ceil(math.log2(len(t)))
    motion, motion_freq = _power(predicted / noise, whole), np.fft.rfftfreq(whole, dt)
    motion_share = float(motion[np.abs(motion_freq - freq[k]) <= band].sum() / max(motion[1:].sum(), 1e-300))
    if peak_share < MIN_PEAK_SHARE or motion_share > MAX_MOTION_SHARE:
        return out
    swings = []
    for a, b in runs:
        if b - a >= 8:  # the swing along the stretch's main direction (noise-weighted, over the six channels)
            u_, s_, _ = np.linalg.svd(z[a:b] - z[a:b].mean(axis=0), full_matrices=False)
            swing = _swing(u_[:, 0] * s_[0], dt, float(freq[k]))
            if swing is not None:
                swings.append(swing)
    out["ringing"] = {
        "frequency_hz": float(np.median([f for f, _ in swings])) if swings else float(freq[k]),
        "damping_ratio": float(np.median([z for _, z in swings])) if swings else None,
        "peak_share": peak_share,
        "motion_share": motion_share,
        "stretches": len(runs),
    }
    return out


def set_aside_notes(gate: dict[str, Any], contact_free: bool | None) -> list[str]:
    """The notes on what the gate set aside: ringing found in it, or a contact-free file with rows set aside."""
    notes = []
    ring = gate["ringing"]
    if ring is not None:
        damping = (
            f", damping ratio {ring['damping_ratio']:.3g}"
            if ring["damping_ratio"] is not None
            else ", its damping unclear"
        )
        did = "set aside" if gate.get("applied", True) else "would have set aside (it was not applied)"
        notes.append(
            f"the contact gate {did} {100 * gate['share']:.1f} % of the rows in {gate['stretches']} stretches, "
            f"and they ring: {100 * ring['peak_share']:.0f} % of their power at {ring['frequency_hz']:.3g} Hz"
            f"{damping}, a frequency the motion does not contain ({100 * ring['motion_share']:.2g} % of its power): "
            f"a ringing tool (a flexible shaft, a loose clamp swinging after each stop), not contact; every figure "
            f"here is over the rows between the swings"
        )
    elif contact_free and gate["share"] > CONTACT_FREE_SHARE:
        notes.append(
            f"the file is described as contact-free, yet the contact gate set aside {100 * gate['share']:.1f} % of "
            f"the rows in {gate['stretches']} stretches: something the model does not explain is that far off "
            f"there; see --plots"
        )
    return notes
