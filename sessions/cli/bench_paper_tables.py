"""``hapticlab bench paper``'s tables: the paper's Tables I–III and figures' numbers, ours beside the paper's."""

from __future__ import annotations

from rich.table import Table

from hapticlab.sessions.cli.render import fmt, wide_console


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
        "information form",
        "paper (samples)",
        "truth-based",
    ):
        t.add_column(col, justify="right")
    t.add_row(
        "force",
        str(conv["force_paper"]),
        "",
        str(conv.get("force_paper_information")),
        str(paper["convergence"]["force_paper"]),
        str(conv["force_truth"]),
    )
    t.add_row(
        "torque",
        str(conv["torque_paper"]),
        str(conv["torque_paper_after_force"]),
        str(conv.get("torque_paper_information")),
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
