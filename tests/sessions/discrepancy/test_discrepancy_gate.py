"""What the contact gate sets aside (``sessions/discrepancy/gated.py``, issue 43): its share, and a ringing
tool told from contact.

A ringing tool is the simulator's :class:`~hapticlab.plugins.simworld.ringing.Ringing`: the flexible part of
the tool swings after each stop of the lively 30 s, 250 Hz tour of ``test_discrepancy`` (a free damped
oscillation, kicked by the tip's speed), seeds used nowhere else.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from hapticlab.plugins.simworld import Indentation, RandomTour, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.plugins.simworld.ringing import Ringing
from hapticlab.sessions.discrepancy.settings import Settings
from hapticlab.sessions.discrepancy.workflow import discrepancy


def recording(tmp_path, seed: int, contacts=(), ringing: dict | None = None):
    motion = RandomTour(seed=seed, segment_s=1.0, max_translation=0.05)
    contacts = list(contacts)
    if ringing is not None:
        contacts.append(Ringing.after_stops(motion, 30.0, **ringing))
    world = SimWorld(motion=motion, contacts=contacts, seed=seed, inertia=False)
    path = tmp_path / f"gate_{seed}.csv"
    write_csv(world, path, 30.0, 250.0)
    return path


def test_the_simulated_ringing_is_a_damped_swing_after_each_stop():
    """The force starts at each stop, along the tip's velocity before it, and is the damped sine of the record:
    its zero crossings half a damped period apart, its peaks decaying by exp(−ζω·T/2) each."""
    motion = RandomTour(seed=310, segment_s=1.0)
    ring = Ringing.after_stops(motion, 10.0, frequency_hz=8.0, damping_ratio=0.05, mass=0.02)
    assert len(ring.stops_s) == 10 and np.all(np.abs(ring.stops_s - np.round(ring.stops_s)) < 0.03)
    t = np.arange(0.0, 10.0, 1e-4)
    force = ring.force_B(t, np.zeros(3))
    assert not force[t < ring.stops_s[0]].any()
    first = (t >= ring.stops_s[0]) & (t < ring.stops_s[1])
    along = force[first] @ ring.velocity_B[0] / np.linalg.norm(ring.velocity_B[0])
    omega_d = 2 * math.pi * 8.0 * math.sqrt(1 - 0.05**2)
    crossings = t[first][1:][np.diff(np.sign(along)) != 0]
    np.testing.assert_allclose(np.diff(crossings[:6]), math.pi / omega_d, atol=2e-4)  # a 0.1 ms grid
    peaks = [np.abs(along[(t[first] >= a) & (t[first] < b)]).max() for a, b in itertools.pairwise(crossings[:5])]
    np.testing.assert_allclose(
        np.array(peaks[1:]) / peaks[:-1], math.exp(-0.05 * 2 * math.pi * 8.0 * math.pi / omega_d), rtol=0.01
    )


@pytest.mark.parametrize(
    ("seed", "frequency_hz", "damping_ratio", "mass"),
    [(311, 8.0, 0.05, 0.02), (312, 12.0, 0.03, 0.01), (313, 6.0, 0.05, 0.03)],
)
def test_a_ringing_tool_is_reported_not_hidden_as_contact(tmp_path, seed, frequency_hz, damping_ratio, mass):
    """A contact-free recording whose tool rings after each stop: the gate sets aside 5-20 % of it, which the
    report said nothing about (it named nothing and flagged only a leftover). Now the share and the stretches are
    in ``contact_gate``, ``warnings.ringing`` is raised and a note gives the frequency (within 3 % of the damped
    one) and the damping ratio (within 35 %: the swings of successive stops overlap), and says it is not contact."""
    path = recording(
        tmp_path, seed, ringing={"frequency_hz": frequency_hz, "damping_ratio": damping_ratio, "mass": mass}
    )
    result = discrepancy(path)
    gate = result["contact_gate"]
    assert gate["rows"] == result["gated"] and gate["share"] == pytest.approx(result["gated"] / result["usable"])
    assert gate["share"] > 0.05 and gate["stretches"] >= 3
    assert result["warnings"]["ringing"] and result["effects"] == []
    ring = gate["ringing"]
    assert ring["frequency_hz"] == pytest.approx(frequency_hz * math.sqrt(1 - damping_ratio**2), rel=0.03)
    assert ring["damping_ratio"] == pytest.approx(damping_ratio, rel=0.35)
    assert ring["motion_share"] < 0.01 and ring["peak_share"] > 0.4
    assert any("they ring" in note and "not contact" in note for note in result["notes"])


def test_presses_are_contact_not_ringing_and_a_contact_free_file_says_so(tmp_path):
    """Eleven 0.6 s presses (1.5 N) and three 1.5 s ones (2.5 N): set aside (37 %, 18 %), not called ringing (they
    rise and fall at the motion's own frequencies). Described as contact-free, the same file gets a note and
    ``warnings.gated_on_contact_free``; a clean file described so gets neither."""
    short = [Indentation(start=s, duration=0.6, peak_force=1.5, ramp=0.1) for s in np.arange(2.0, 28.0, 2.5)]
    long = [Indentation(start=s, duration=1.5, peak_force=2.5) for s in (5.0, 14.0, 23.0)]
    for seed, contacts in ((314, short), (315, long)):
        path = recording(tmp_path, seed, contacts=contacts)
        result = discrepancy(path)
        assert result["contact_gate"]["share"] > 0.1 and result["contact_gate"]["stretches"] == len(contacts)
        assert result["contact_gate"]["ringing"] is None and not result["warnings"]["ringing"]
        assert not result["warnings"]["gated_on_contact_free"]
        described = discrepancy(path, Settings(contact_free=True))
        assert described["warnings"]["gated_on_contact_free"]
        assert any(note.startswith("the file is described as contact-free") for note in described["notes"])
    clean = discrepancy(recording(tmp_path, 316), Settings(contact_free=True))
    assert clean["gated"] == 0 and not any(clean["warnings"].values()) and clean["contact_gate"]["stretches"] == 0


def test_a_ringing_tool_the_gate_is_not_applied_to_is_still_told_from_contact(tmp_path):
    """A stronger ringing (10 Hz, damping ratio 0.1, 50 g): the gate would set aside 60 % of the rows, so it is
    not applied, and the note said only that the recording had that much contact. The rows it would have set
    aside are looked at all the same: they ring, at the damped frequency, and the note says so."""
    path = recording(tmp_path, 353, ringing={"frequency_hz": 10.0, "damping_ratio": 0.1, "mass": 0.05})
    result = discrepancy(path)
    gate = result["contact_gate"]
    assert result["warnings"]["gate_not_applied"] and result["gated"] == 0 and not gate["applied"]
    assert gate["share"] > 0.5 and result["warnings"]["ringing"]
    assert gate["ringing"]["frequency_hz"] == pytest.approx(10.0 * math.sqrt(1 - 0.1**2), rel=0.03)
    assert gate["ringing"]["damping_ratio"] == pytest.approx(0.1, rel=0.35)
    assert any(
        note.startswith("the contact gate would have set aside (it was not applied)") for note in result["notes"]
    )
