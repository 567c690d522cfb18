"""The tables of ``hapticlab bench estimators``, ``real``, ``faults``, ``loop`` and ``teleop``."""

from __future__ import annotations

from rich.table import Table

from hapticlab.sessions.bench.real import REAL_COLUMNS, table_rows
from hapticlab.sessions.cli.render import fmt, wide_console


def print_estimators_table(out: dict) -> None:
    """One row per scenario and estimator variant: the numbers the family's targets name."""
    t = Table(title="Estimator family, simulated at 1 kHz, 0.12 N noise unless said")
    for col in ("scenario", "estimator", "RMS / noise fx, fy, fz", "other"):
        t.add_column(col, justify="right")

    def rms_rows(name: str, rows: dict, other: dict[str, str]) -> None:
        for k, (label, values) in enumerate(rows.items()):
            t.add_row(
                name if k == 0 else "",
                label,
                ", ".join(fmt(v, 3) for v in values),
                other.get(label, ""),
                end_section=k == len(rows) - 1,
            )

    m = out["mount"]
    rms_rows(
        "5° mount (last 15 s)",
        m["rms_over_noise_last_15s"],
        {"kalman mount_rotation": f"estimated within {m['mount_error_deg']:.3f}°"},
    )
    i = out["inertia_tour"]
    rms_rows(
        "inertia, random tour",
        i["rms_over_noise_last_15s"],
        {"rls": "inertial force RMS " + ", ".join(fmt(v, 3) for v in i["inertial_force_rms_N"]) + " N"},
    )
    r = out["rotation_104g"]
    for k, (label, n) in enumerate(r["estimators"].items()):
        t.add_row(
            f"104 g at {r['speed_deg_s']:.0f} deg/s (¼ noise)" if k == 0 else "",
            label,
            "",
            f"Max AE {n['max_ae']:.3f} N per sample, {n['max_ae_10ms']:.3f} N over 10 ms; MAE {n['mae']:.3f} N",
            end_section=k == len(r["estimators"]) - 1,
        )
    rms_rows(
        f"kinematics {out['time_lag']['lag_s'] * 1000:.0f} ms late", out["time_lag"]["rms_over_noise_last_10s"], {}
    )
    rms_rows("2 % calibration error", out["gain"]["rms_over_noise_last_10s"], {})
    p = out["payload"]
    if p.get("recognised_after_s") is None:
        t.add_row("100 g payload", "kalman", "", "not recognised")
    else:
        force, torque = p["force_flag_up_after_hang_s"], p["torque_flag_up_after_event_s"]
        t.add_row(
            "100 g payload",
            "kalman",
            "",
            f"recognised {p['recognised_after_s']:.3f} s after the hang; force flag up "
            f"{'never' if force is None else f'{force:.3f} s after it'}; torque flag "
            f"{'never' if torque is None else f'{torque:.3f} s after the event'}",
        )
    wide_console(140).print(t)


def print_real_table(out: dict) -> None:
    """One row per file and estimator."""
    t = Table(
        title="Real recordings: online RMS over every row after convergence, against the offline batch "
        "fit over the same rows; and the ‖·‖ ratio over the file's second half. Contact: rows judged "
        "a contact (every one a false contact here); held out: rows refused but not called a contact; last 70 %: "
        "the worst axis's RMS over the batch fit's on the file's last 70 % of rows, force and torque"
    )
    for col in REAL_COLUMNS:
        t.add_column(col, justify="right")

    def listed(values, digits: int) -> str:
        return ", ".join(fmt(v, digits) for v in values or []) or "–"

    for row, last in table_rows(out, fmt, listed):
        t.add_row(*row, end_section=last)
    wide_console(160).print(t)


def print_faults_table(out: dict) -> None:
    """One row per estimator and fault: what reached the hand, how soon it was caught, the event."""
    from hapticlab.sessions.bench.faults import COLUMNS, FAULT_START_S, table_rows

    t = Table(
        title=f"Injected faults (demo session, fault at {FAULT_START_S:g} s): force on the device that the "
        f"contact does not explain, and how soon it went to zero"
    )
    for col in COLUMNS:
        t.add_column(col, justify="right" if col != "event" else "left")
    for row, last in table_rows(out, fmt):
        t.add_row(*row, end_section=last)
    wide_console(140).print(t)


def print_loop_tables(out: dict) -> None:
    """Per stage: µs per tick and share, per sensor rate; per estimator: µs per sample by block size."""
    from hapticlab.sessions.bench.loop import STAGES

    def stage_rows(title: str, runs: list[dict], width: int) -> None:
        t = Table(title=title)
        t.add_column("stage")
        for run in runs:
            t.add_column(f"{run['sensor_rate_hz']:g} Hz sensor, {run['writer']} writer: µs/tick", justify="right")
            t.add_column("share", justify="right")
        for stage in STAGES:
            if any(run["us_per_tick"][stage] for run in runs) or stage == "loop body":  # a stage this preset has
                t.add_row(
                    stage,
                    *[
                        v
                        for run in runs
                        for v in (f"{run['us_per_tick'][stage]:.1f}", f"{100 * run['share'][stage]:.0f} %")
                    ],
                )
        t.add_row(
            "whole tick",
            *[v for run in runs for v in (f"{sum(run['us_per_tick'].values()):.1f}", "")],
            end_section=True,
        )
        t.add_row("× real time", *[v for run in runs for v in (f"{run['x_real_time']:.2f}", "")], end_section=True)
        t.add_row("start and end, ms once", *[v for run in runs for v in (f"{run['start_end_ms']:.0f}", "")])
        t.add_row(
            f"× real time, whole {runs[0]['duration_s']:g} s run",
            *[v for run in runs for v in (f"{run['x_real_time_session']:.2f}", "")],
            end_section=all("bare" in run for run in runs),
        )
        if all("bare" in run for run in runs):  # the same session run again, only its ticks timed
            t.add_row(
                "no stopwatches: whole tick", *[v for run in runs for v in (f"{run['bare']['us_per_tick']:.1f}", "")]
            )
            t.add_row(
                "no stopwatches: × real time", *[v for run in runs for v in (f"{run['bare']['x_real_time']:.2f}", "")]
            )
            t.add_row(
                f"no stopwatches: × real time, whole {runs[0]['duration_s']:g} s run",
                *[v for run in runs for v in (f"{run['bare']['x_real_time_session']:.2f}", "")],
            )
        wide_console(width).print(t)

    stages = out["stages"]
    stage_rows(
        "Where a tick goes (demo session, not paced, recording on; loop at "
        f"{stages[0]['loop_rate_hz']:g} Hz, estimator {stages[0]['estimator']})",
        stages,
        160,
    )
    if "teleop" in out:
        run = out["teleop"]
        shadows = f", shadows {', '.join(run['shadows'])}" if run["shadows"] else ""
        stage_rows(
            f"Where a tick goes in teleoperation ({run['preset']}, a master pressing 5 cm every 2 s after "
            f"the tour, not paced; estimator {run['estimator']}{shadows})",
            [run],
            100,
        )
    t = Table(title="Estimators: µs per sample (median / p99) by block size, simulated tour at 1 kHz")
    t.add_column("estimator")
    sizes = list(next(iter(out["estimators"].values())))
    for size in sizes:
        t.add_column(f"block {size}", justify="right")
    for label, row in out["estimators"].items():
        t.add_row(label, *[f"{row[s]['median_us']:.1f} / {row[s]['p99_us']:.1f}" for s in sizes])
    wide_console(120).print(t)


def print_teleop_table(out: dict) -> None:
    """One row per stiffness, delay and passivity: the port's energy, the oscillation, the transparency."""
    from hapticlab.sessions.bench.teleop import COLUMNS, table_rows

    t = Table(title="teleop-sim: the hand presses the tool into tissue through a delayed link")
    for col in COLUMNS:
        t.add_column(col, justify="right")
    for row, last in table_rows(out, fmt):
        t.add_row(*row, end_section=last)
    wide_console(160).print(t)
