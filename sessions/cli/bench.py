"""``hapticlab bench paper|estimators|real``: the benchmarks, printed as the paper's tables and ours."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.table import Table

from hapticlab.core.errors import UserError
from hapticlab.sessions.cli.offline import add_force
from hapticlab.sessions.cli.render import err, finite_json, fmt, wide_console
from hapticlab.sessions.output import check_output, check_plots_folder, write_text


def print_paper_tables(out: dict) -> None:
    """The paper's tables, ours beside the paper's numbers."""
    paper = out["paper"]
    conv = out["convergence"]
    out_console = out_table = wide_console(120)
    t = Table(title="Convergence (0-based sample index in the identification run; never = None)")
    for col in (
        "stage",
        "paper's ‖Δx‖ < 1e-3",
        "samples after force",
        "the same, P as printed",
        "paper (samples)",
        "truth-based",
    ):
        t.add_column(col, justify="right")
    t.add_row(
        "force",
        str(conv["force_paper"]),
        "",
        str(conv.get("force_paper_printed")),
        str(paper["convergence"]["force_paper"]),
        str(conv["force_truth"]),
    )
    t.add_row(
        "torque",
        str(conv["torque_paper"]),
        str(conv["torque_paper_after_force"]),
        str(conv.get("torque_paper_printed")),
        str(paper["convergence"]["torque_paper"]),
        str(conv["torque_truth"]),
    )
    out_console.print(t)
    ident = out["identification"]
    t = Table(title=f"Identified parameters after {ident['samples']} samples")
    for col in ("parameter", "estimator", "batch fit, same samples", "truth"):
        t.add_column(col, justify="right")
    for key, scale, unit in (
        ("gravity_force_B", 1, "N"),
        ("bias_force_S", 1, "N"),
        ("cog_S", 1000, "mm"),
        ("bias_torque_S", 1, "N·m"),
    ):
        row = [", ".join(fmt(v * scale, 3) for v in ident[src][key]) for src in ("params", "batch_fit", "truth")]
        t.add_row(f"{key} ({unit})", *row)
    out_console.print(t)
    for group, title, unit in (
        ("force", "Table I: force error statistics", "N"),
        ("torque", "Table II: torque error statistics", "N·m"),
    ):
        t = Table(title=f"{title} ({out['no_contact']['poses']} random poses, {unit})")
        for col in (
            "component",
            "condition",
            "MAE",
            "Max AE",
            "Std",
            "MAE comp.",
            "Std/noise",
            "paper MAE",
            "paper Max AE",
            "paper Std",
            "paper comp.",
        ):
            t.add_column(col, justify="right")
        for axis, ours in out["no_contact"][group].items():
            ref = paper["no_contact"][group][axis]
            digits = 3
            t.add_row(
                axis,
                "before",
                fmt(ours["mae_before"], digits),
                fmt(ours["max_before"], digits),
                fmt(ours["std_before"], digits),
                f"{ours['mae_comp_pct']:.1f} %",
                "",
                fmt(ref["mae_before"]),
                fmt(ref["max_before"]),
                fmt(ref["std_before"]),
                f"{ref['mae_comp_pct']:.1f} %",
            )
            t.add_row(
                "",
                "after",
                fmt(ours["mae_after"], digits),
                fmt(ours["max_after"], digits),
                fmt(ours["std_after"], digits),
                "",
                fmt(ours["std_after_over_noise"], 2),
                fmt(ref["mae_after"]),
                fmt(ref["max_after"]),
                fmt(ref["std_after"]),
                "",
                end_section=True,
            )
        out_table.print(t)
    t = Table(title="Table III: compensation error bounds over the random poses (±)")
    for col in ("component", "batch fit, held", "rls, frozen", "rls, running", "Yu et al. (paper)", "proposed (paper)"):
        t.add_column(col, justify="right")
    for axis in ("fx", "fy", "fz", "tx", "ty", "tz"):
        t.add_row(
            axis,
            fmt(out["bounds"].get("batch", {}).get(axis)),
            fmt(out["bounds"].get("rls_frozen", {}).get(axis)),
            fmt(out["bounds"]["rls"][axis]),
            fmt(paper["bounds"]["yu2021"][axis]),
            fmt(paper["bounds"]["rls"][axis]),
        )
    out_console.print(t)
    out_console.print(
        "  batch fit and frozen rls: identified on the 20 s tour, then held; running rls keeps "
        "learning during the poses, as the paper's does"
    )
    ind = out["indentation"]
    out_console.print(
        f"Phantom indentation ({ind['contacts']} contacts): plateau detected {ind['detected_plateau_pct']:.1f} %, "
        f"false contact {ind['false_contact_pct']:.2f} %, RMS between contacts "
        f"[{', '.join(fmt(v) for v in ind['rms_free'])}] N, error in contact "
        f"[{', '.join(fmt(v) for v in ind['rms_error_in_contact'])}] N"
    )
    t = Table(title="104 g reference mass (|contact force| against 1.02 N), one turn per speed")
    for col in ("deg/s", "MAE", "Max AE", "Std", "mean", "MAE, low noise", "Max AE, low noise", "Std, low noise"):
        t.add_column(col, justify="right")
    for speed in ("12", "30", "45", "72"):
        a, b = out["rotation_104g"][speed], out["rotation_104g_low_noise"][speed]
        t.add_row(
            speed,
            fmt(a["mae"]),
            fmt(a["max_ae"]),
            fmt(a["std"]),
            fmt(a["mean"]),
            fmt(b["mae"]),
            fmt(b["max_ae"]),
            fmt(b["std"]),
        )
    out_console.print(t)
    out_console.print(
        f"  paper: MAE ≤ 0.04 N, Max AE 0.119 N at 72 deg/s, Std < 0.046 N; noise per axis "
        f"{out['rotation_104g']['noise_force']} N, low noise {out['rotation_104g_low_noise']['noise_force']} N"
    )
    r = out["repeated_rows"]
    out_console.print(
        f"Repeated rows (40 poses × 5 identical rows, like the LWR4 logs): force 'converged' at row "
        f"{r['converged_force_at']}, then {r['refused_pct']:.1f} % of the (contact-free) rows refused as contact, "
        f"RMS [{', '.join(fmt(v) for v in r['rms_force_S'])}] N"
    )
    d = out["drift_contact"]
    out_console.print(
        f"Bias drift {d['drift_N_per_min']} N/min with an indentation every 10 s ({d['duration_s']:.0f} s): "
        f"{d['false_contact_pct']:.1f} % of no-contact samples refused as contact "
        f"({d['false_contact_last_30s_pct']:.1f} % over the last 30 s), "
        f"RMS without contact over the last 30 s [{', '.join(fmt(v) for v in d['rms_free_last_30s'])}] N "
        f"(noise {d['noise_force']} N)"
    )


def cmd_bench(args: argparse.Namespace) -> int:
    import json

    if args.which != "paper" and (args.plots or args.quick or args.all_estimators):
        raise UserError("--plots, --quick and --all-estimators go with 'bench paper'")
    if args.which != "real" and args.folder:
        raise UserError(f"'bench {args.which}' takes no folder (got {args.folder!r}); did you mean 'bench real'?")
    # where the results go is checked before the benchmarks run, so a finished run is not lost to a bad path
    if args.json:
        check_output(args.json, args.force, label="--json")
    if args.plots:
        from hapticlab.sessions.bench.paper_plots import FIGURES

        check_plots_folder(args.plots, args.force, patterns=FIGURES)
    if args.which == "paper":
        from hapticlab.sessions.bench.paper import bench_paper
        from hapticlab.sessions.bench.paper_plots import write_plots

        with err.status("running the paper's experiments") as status:
            out, plots = bench_paper(
                quick=args.quick,
                all_estimators=args.all_estimators,
                progress=lambda m: status.update(f"bench paper: {m}"),
            )
        print_paper_tables(out)
        if args.plots:
            for path in write_plots(plots, Path(args.plots), force=args.force):
                err.print(f"wrote {path}")
    elif args.which == "estimators":
        from hapticlab.sessions.bench.family import bench_estimators

        with err.status("running the estimator family's scenarios") as status:
            out = bench_estimators(progress=lambda m: status.update(f"bench estimators: {m}"))
        print_estimators_table(out)
    elif args.which == "loop":
        from hapticlab.sessions.bench.loop import bench_loop

        with err.status("timing the run loop") as status:
            out = bench_loop(progress=lambda m: status.update(f"bench loop: {m}"))
        print_loop_tables(out)
    elif args.which == "faults":
        from hapticlab.sessions.bench.faults import bench_faults

        with err.status("injecting faults into the run loop") as status:
            out = bench_faults(progress=lambda m: status.update(f"bench faults: {m}"))
        print_faults_table(out)
    else:
        from hapticlab.sessions.bench.real import bench_real, default_real_dir

        folder = Path(args.folder) if args.folder else default_real_dir()
        with err.status("evaluating real recordings") as status:
            out = bench_real(folder, progress=lambda m: status.update(f"bench real: {m}"))
        print_real_table(out)
        if all("error" in entry for entry in out.values()):
            raise UserError(f"{folder}: none of its {len(out)} CSV file(s) could be evaluated (see the table)")
    if args.json:
        write_text(args.json, json.dumps(finite_json(out), indent=2) + "\n", args.force, label="--json")
        err.print(f"wrote {args.json}")
    return 0


def print_faults_table(out: dict) -> None:
    """One row per estimator and fault: what reached the hand, how soon it was caught, the event."""
    from hapticlab.sessions.bench.faults import FAULT_START_S

    t = Table(
        title=f"Injected faults (demo session, fault at {FAULT_START_S:g} s): force on the device that the "
        f"contact does not explain, and how soon it went to zero"
    )
    for col in ("estimator", "fault", "made-up force (N)", "detected after (ms)", "zero after detection (ms)", "event"):
        t.add_column(col, justify="right" if col != "event" else "left")
    for estimator, faults in out.items():
        for k, (label, r) in enumerate(faults.items()):
            ms = lambda v: "never" if v is None else f"{1e3 * v:.0f}"  # noqa: E731
            t.add_row(
                estimator if k == 0 else "",
                label,
                fmt(r["made_up_force_N"], 2),
                ms(r["detected_after_s"]),
                ms(r["zero_after_detection_s"]),
                r["event"] or "none",
                end_section=k == len(faults) - 1,
            )
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


def print_estimators_table(out: dict) -> None:
    """One row per scenario and estimator variant: the numbers the issue's targets name."""
    t = Table(title="Estimator family (issue 4), simulated at 1 kHz, 0.12 N noise unless said")
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
        "a contact (every one a false contact here); held out: rows refused but not called a contact"
    )
    for col in (
        "file",
        "estimator",
        "force conv.",
        "torque conv.",
        "contact",
        "held out",
        "RMS fx, fy, fz (N)",
        "batch, same rows",
        "ratio per axis",
        "ratio ‖·‖",
        "2nd half",
    ):
        t.add_column(col, justify="right")
    for name, entry in out.items():
        if "error" in entry:
            t.add_row(name, "", "", "", "", "", entry["error"], "", "", "", "", end_section=True)
            continue
        for k, (est_name, r) in enumerate(entry["estimators"].items()):
            if "error" in r:
                t.add_row(
                    name if k == 0 else "",
                    est_name,
                    "",
                    "",
                    "",
                    "",
                    r["error"],
                    "",
                    "",
                    "",
                    "",
                    end_section=k == len(entry["estimators"]) - 1,
                )
                continue
            if est_name.endswith("named effects"):
                est_name += " (" + (", ".join(entry.get("named_effects", [])) or "none") + ")"
            rms = ", ".join(fmt(v) for v in r.get("rms_force_S", [])) or "never converged"
            batch = ", ".join(fmt(v) for v in r.get("batch_rms_same_rows", [])) or "–"
            ratio = ", ".join(fmt(v, 2) for v in r.get("ratio", [])) or "–"
            held_out = f"{r['held_out_pct']:.1f} % ({r['held_out_rows']})" if "held_out_pct" in r else "–"
            t.add_row(
                name if k == 0 else "",
                est_name,
                str(r["converged_force_at"]),
                str(r["converged_torque_at"]),
                f"{r['contact_pct']:.1f} % ({r['contact_rows']})",
                held_out,
                rms,
                batch,
                ratio,
                fmt(r.get("ratio_norm"), 2),
                fmt(r.get("ratio_norm_second_half"), 2),
                end_section=k == len(entry["estimators"]) - 1,
            )
    wide_console(140).print(t)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``hapticlab`` parser."""
    p = sub.add_parser(
        "bench",
        help="reproduce the paper's experiments (paper), measure the estimator family "
        "(estimators), evaluate real recordings (real) or inject faults into sessions (faults)",
    )
    p.add_argument(
        "which",
        choices=("paper", "estimators", "real", "faults", "loop"),
        help="paper: simulated experiments; estimators: issue 4's scenarios; real: CSV folder; "
        "faults: every injected fault through the run loop; loop: where a tick goes, "
        "per stage, and each estimator's µs per sample",
    )
    p.add_argument(
        "folder", nargs="?", default=None, help="with real: folder of CSV files (default ../shared/data/real)"
    )
    p.add_argument("--json", default=None, help="write every number as JSON")
    p.add_argument("--plots", default=None, help="with paper: write the figures as PNG into this folder")
    p.add_argument("--quick", action="store_true", help="with paper: a shorter run (smoke test)")
    p.add_argument("--all-estimators", action="store_true", help="with paper: repeat for every registered estimator")
    add_force(p)
    p.set_defaults(func=cmd_bench)
