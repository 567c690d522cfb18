"""``docs/results.md``'s sections on the simulated estimator family, the injected faults and the teleoperation loop."""

from __future__ import annotations

from typing import Any

from hapticlab.sessions.bench.report_markdown import num, table, vec


def estimators_section(out: dict[str, Any]) -> list[str]:
    """``hapticlab bench estimators``: each effect the paper leaves out, and the estimator options that model it."""
    lines = [
        "## The estimator family, in simulation",
        "",
        "`hapticlab bench estimators` (JSON: `docs/results/estimators.json`): simulated at 1 kHz, 0.12 N noise",
        "unless said. \"RMS / noise\" is the compensated force's RMS over the scenario's last seconds divided by",
        "the simulated noise (1 is the floor). `kalman` is the estimator with its defaults (its biases walk with",
        "time and with the tool's tilt); `kalman bias_force_tilt_rw=0` is the paper's model alone; `kalman`",
        "with an option's name models that effect ([estimators.md](estimators.md)).",
        "",
    ]
    rows: list[tuple[str, ...]] = []

    def rms_rows(scenario: str, values: dict[str, list[float]], other: dict[str, str]) -> None:
        for k, (label, v) in enumerate(values.items()):
            rows.append((scenario if k == 0 else "", f"`{label}`", vec(v), other.get(label, "")))

    m = out["mount"]
    rms_rows(
        "5° mount (last 15 s)",
        m["rms_over_noise_last_15s"],
        {"kalman mount_rotation": f"mount estimated within {m['mount_error_deg']:.3f}°"},
    )
    i = out["inertia_tour"]
    rms_rows(
        "inertia, random tour",
        i["rms_over_noise_last_15s"],
        {"rls": f"inertial force RMS {vec(i['inertial_force_rms_N'])} N"},
    )
    r = out["rotation_104g"]
    for k, (label, n) in enumerate(r["estimators"].items()):
        rows.append(
            (
                f"104 g at {r['speed_deg_s']:.0f} deg/s (¼ noise)" if k == 0 else "",
                f"`{label}`",
                "",
                f"Max AE {n['max_ae']:.3f} N per sample, {n['max_ae_10ms']:.3f} N over 10 ms; MAE {n['mae']:.3f} N",
            )
        )
    rms_rows(
        f"kinematics {1000 * out['time_lag']['lag_s']:.0f} ms late (last 10 s)",
        out["time_lag"]["rms_over_noise_last_10s"],
        {},
    )
    rms_rows("2 % calibration error (last 10 s)", out["gain"]["rms_over_noise_last_10s"], {})
    p = out["payload"]
    if p.get("recognised_after_s") is None:
        rows.append(("100 g payload", "`kalman`", "", "not recognised"))
    else:
        force, torque = p["force_flag_up_after_hang_s"], p["torque_flag_up_after_event_s"]
        rows.append(
            (
                "100 g payload",
                "`kalman`",
                "",
                f"recognised {p['recognised_after_s']:.3f} s after the hang; force flag up "
                f"{'never' if force is None else f'{force:.3f} s after it'}; torque flag "
                f"{'never' if torque is None else f'{torque:.3f} s after the event'}",
            )
        )
    lines += table(("scenario", "estimator", "RMS / noise fx, fy, fz", "other"), rows, align="llrl")
    lines += [
        "The 104 g turn at 72 deg/s is about the instrument's own axis, on which its centre of mass lies, so",
        "`inertia = true` changes little there; its effect shows on the tour that turns and translates.",
        "",
    ]
    return lines


def faults_section(out: dict[str, Any]) -> list[str]:
    """``hapticlab bench faults``: each injected fault, what reached the hand and how soon it was stopped."""
    lines = [
        "## Injected faults",
        "",
        "`hapticlab bench faults` (JSON: `docs/results/faults.json`): each fault injected into the demo session",
        '(`[[world.faults]]`), the same session run once without it, every seed shared. "Made-up force" is the',
        'largest force on the device the clean run\'s contact does not explain, N; "over 0.5 N for", how long it',
        'was above 0.5 N; "detected after", from the fault\'s start to the first zero command naming a fault;',
        '"zero after detection", from there to the zero command. The rules: [safety.md](safety.md).',
        "",
    ]

    from hapticlab.sessions.bench.faults import COLUMNS, table_rows

    rows = [row for row, _ in table_rows(out, num, name=lambda estimator: f"`{estimator}`")]
    lines += table(COLUMNS, rows, align="llrrrrl")
    return lines


def teleop_section(out: dict[str, Any], figures: str = "results") -> list[str]:
    """``hapticlab bench teleop``: the closed loop's energy, oscillation and transparency."""
    lines = [
        "## Teleoperation: stability and transparency",
        "",
        "`hapticlab bench teleop --plots docs/results` (JSON: `docs/results/teleop.json`): the `teleop-sim` preset, a",
        "simulated hand on a simulated master pressing the tool into tissue through a link delayed each way, with",
        'the passivity controller on and off. "Max energy" is the most the haptic port had put into the hand,',
        "computed from the recorded forces and handle velocities (> 0: an active port); the force's standard",
        "deviation and the handle's travel are taken in steady contact; the transparency is the RMS difference",
        "there between the force felt and the contact force the robot's side estimated. The method:",
        "[teleoperation.md](teleoperation.md).",
        "",
    ]
    from hapticlab.sessions.bench.teleop import COLUMNS, table_rows

    lines += table([str(c) for c in COLUMNS], [row for row, _ in table_rows(out, num)], align="lllr")
    lines += ["", f"![force and energy, worst case]({figures}/teleop_energy.png)", ""]
    return lines
