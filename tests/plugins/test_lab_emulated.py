"""End to end over the real wire protocols: `hapticlab emulate lab` in one process, a session in another.

`hapticlab emulate lab` serves a Net F/T (RDT over UDP, netftapi2.xml over HTTP) and a UR5e
(RTDE) from one simulated world; the session reads them through `netft`
(its RDT receiver, the calibration from the XML page) and `ur_rtde`
(ur-rtde's own RTDEReceiveInterface), as it would read the real devices. The
world's physics is known, so the compensated contact force is checked against
the contact that was really there. (ur-rtde's client must not share a process
with the emulator: its constructor holds the GIL while it waits.)
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from processes import hapticlab_command

from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.recording import read_recording

NETFT, UR = "127.0.0.92", "127.0.0.93"  # addresses of their own: ur-rtde always uses port 30004


@pytest.fixture
def lab(spawn_process):
    """The lab process, serving for at most 60 s; yields its world's t0 on the monotonic clock (ns)."""
    proc = spawn_process(
        hapticlab_command("emulate", "lab", "--netft", NETFT, "--ur", UR, "--duration", "60"), "emulate lab"
    )
    line = proc.first_line()
    assert line.startswith("lab: Net F/T on 127.0.0.92"), line
    yield int(line.rsplit("t0_ns=", 1)[1])
    proc.finish()


def test_a_session_on_the_emulated_lab_feels_the_contact_the_world_made(tmp_path, lab, paced_run):
    config, _ = load_config("lab-emulated")
    config = apply_overrides(config, [f"sensor.address={NETFT}", f"kinematics.address={UR}", "session.duration=12"])
    result = paced_run(build_session(config), tmp_path / "lab.mcap")
    rec = read_recording(result.path)

    # what the devices delivered: 1 kHz RDT records and 500 Hz RTDE packages, each stream gap-free or its gaps
    # counted (lost records, missed packages), and most of each read (its counters, not the wall clock's span)
    seq = rec.field("/sensor/wrench", "seq").astype(np.int64)
    lost = [e for e in rec.events if e.kind == "sensor_health"][-1].data["lost"]
    assert len(seq) == result.samples and (seq[-1] - seq[0]) // 7 + 1 == result.samples + lost  # 7 kHz counter
    missed = max([e.data["missed_total"] for e in rec.events if e.kind == "kinematics_missed"], default=0)
    assert result.samples >= 0.95 * (result.samples + lost) and result.poses >= 0.6 * (result.poses + missed)
    assert float(rec.metadata["hapticlab.calibration"]["counts_per_force"]) == 1e6  # read from netftapi2.xml
    assert result.first_converged_force is not None and result.haptic_on_s > 2.0

    # the compensated contact force against the world's contact, where the estimator is converged
    t_ns = rec.t_ns("/estimator/rls")
    world_t = (t_ns - lab) * 1e-9
    estimated = rec.field("/estimator/rls", "contact_force_S")
    converged = rec.field("/estimator/rls", "converged_force").astype(bool)
    truth = SimWorld.from_config(config["world"]).wrench(world_t, noise=False)["contact_force_S"]
    after = converged & (world_t > world_t[np.argmax(converged)] + 1.0)
    assert after.sum() > 3000
    error = np.linalg.norm(estimated[after] - truth[after], axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.3  # N; the sensor's noise is 0.12 N per axis
    # the indentations' plateaus (world t 6.3–7.2 s at 3 N, 9.8–10.7 s at 2 N, 12.75–13.25 s at 4 N): the session
    # starts a few seconds into the world's time, when the lab and the session are up
    pressing = after & (np.linalg.norm(truth, axis=1) > 1.5)
    assert pressing.sum() > 300
    assert np.abs(np.linalg.norm(estimated[pressing], axis=1) - np.linalg.norm(truth[pressing], axis=1)).mean() < 0.3
    ages = np.array([m["age_ns"] for _, m in rec.topics["/kinematics/pose"]]) * 1e-9
    # RTDE's delay, recorded: a 2 ms cycle and the polling (~2-4 ms), more on a loaded machine; never negative
    assert ages.min() >= 0 and 0 < np.median(ages) < 0.05
    assert "ur_rtde" in rec.metadata["hapticlab.session"]["plugins"] and os.path.getsize(result.path) > 0
