"""``hapticlab discrepancy``: the workflow's rounds and steps as tables, its JSON, plots and TOML snippet."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hapticlab.core.errors import UserError
from hapticlab.core.host.registry import Registry
from hapticlab.sessions.cli.offline import add_folder_options, add_force, print_folder_run
from hapticlab.sessions.cli.render import err, fmt, vec, wide_console
from hapticlab.sessions.output import check_output, check_plots_folder, write_text


def print_discrepancy(result: dict) -> None:
    """Candidate tables per round, the steps table, the comparison with the batch fit."""
    import numpy as np
    from rich.table import Table

    console = wide_console(140)
    for note in result["notes"]:
        err.print(f"note: {note}")
    noise = result["noise_estimate"]
    rate = f", {result['rate_hz']:.4g} samples/s" if result["rate_hz"] else ""
    console.print(
        f"[bold]{result['input']}[/]: {result['samples']} rows, {result['usable']} usable, "
        f"{result['gated']} set aside by the contact gate; t in {result['time_base']}{rate}; "
        f"noise estimate {fmt(noise['force_S'][0], 4)} N, {fmt(noise['torque_S'][0], 5)} N·m"
    )
    for skipped in result["skipped"]:
        console.print(f"  not tested: [bold]{skipped['effect']}[/] ({skipped['reason']})")
    folds_rule = result["settings"]
    for i, rnd in enumerate(result["rounds"], start=1):
        need = f"{rnd[0]['wins_needed']} of {rnd[0]['folds']} folds" if rnd else "enough folds"
        t = Table(
            title=f"round {i}: candidates on held-out data (named if gain ≥ "
            f"{100 * folds_rule['min_gain']:g} % and it improves ≥ {need})"
        )
        for col in ("effect", "held-out gain", "folds improved", "t over folds", "verdict"):
            t.add_column(col, justify="right")
        named = next(
            (step["effect"] for step in result["steps"] if step["round"] == i and step["action"] == "named"), None
        )
        for e in sorted(rnd, key=lambda e: -e["heldout_gain"]):
            verdict = (
                "[green]named[/]"
                if e["effect"] == named
                else "significant, smaller"
                if e["significant"]
                else e.get("note") or "not significant"
            )
            t.add_row(
                e["effect"],
                f"{100 * e['heldout_gain']:.2f} %",
                f"{e['folds_improved']}/{e['folds']}",
                fmt(e["t"], 1),
                verdict,
            )
        console.print(t)
    t = Table(title="steps: RMS per axis before → after, on the same samples")
    for col in ("step", "effect", "evidence", "parameters", "force fx, fy, fz (N)", "torque tx, ty, tz (N·m)"):
        t.add_column(col, justify="right" if col != "parameters" else "left")
    t.add_row(
        "0",
        "baseline",
        "",
        "the paper's model",
        vec(result["baseline"]["rms_force_S"]),
        vec(result["baseline"]["rms_torque_S"], 4),
    )
    for i, step in enumerate(result["steps"], start=1):
        ev = step["evidence"]
        effect = {
            "named": step["effect"],
            "dropped": f"− {step['effect']} (dropped)",
            "set_aside": f"− {step['effect']} (set aside)",
        }[step["action"]]
        t.add_row(
            str(i),
            effect,
            f"{100 * ev['heldout_gain']:.1f} %, {ev['folds_improved']}/{ev['folds']} folds",
            step["summary"],
            f"{vec(step['rms_force_before'])} → {vec(step['rms_force_after'])}",
            f"{vec(step['rms_torque_before'], 4)} → {vec(step['rms_torque_after'], 4)}",
        )
    console.print(t)
    final, batch = result["final"], result["batch_fit"]
    ratio = np.linalg.norm(final["rms_force_S"]) / np.linalg.norm(batch["rms_force_S"])
    aside = [step["effect"] for step in result["steps"] if step["action"] == "set_aside"]
    named = ", ".join(result["effects"]) or (
        f"nothing ({', '.join(aside)} set aside by the structure test)"
        if aside
        else "nothing (no candidate is significant)"
    )
    console.print(f"named: [bold]{named}[/]")
    console.print(
        f"final RMS force {vec(final['rms_force_S'])} N, torque {vec(final['rms_torque_S'], 4)} N·m; "
        f"offline batch fit on the same samples {vec(batch['rms_force_S'])} N, "
        f"{vec(batch['rms_torque_S'], 4)} N·m: force RMS norm "
        + (
            f"{100 * (1 - ratio):.1f} % below the batch fit"
            if ratio <= 1
            else f"{100 * (ratio - 1):.1f} % above the batch fit"
        )
    )


def discrepancy_folder_table(args: argparse.Namespace, settings) -> int:
    """``hapticlab discrepancy DIR/``: every recording in the folder, one row each."""
    from hapticlab.sessions.discrepancy.workflow import discrepancy_folder

    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers: at least 1, got {args.workers}")
    run = discrepancy_folder(
        args.input, settings, scheduler=args.scheduler, workers=args.workers, progress=err.is_terminal
    )

    def row(r) -> list[str]:
        named = ", ".join(r["effects"]) or "none"
        left = " ".join(fmt(v, 3) for v in r["final_rms_over_noise"]["force_S"])
        return [str(r["samples"]), named, left, ", ".join(k for k, v in r["warnings"].items() if v) or "–"]

    return print_folder_run(
        run,
        args.input,
        f"{args.input}: {len(run.outcomes)} recordings; the effects named, "
        f"and what is left (force RMS over each axis's noise, x y z)",
        ("rows", "effects named", "left / noise", "warnings"),
        row,
    )


def cmd_discrepancy(args: argparse.Namespace) -> int:
    import json

    from hapticlab.sessions.config import parse_value
    from hapticlab.sessions.discrepancy.plots import FIGURE_PATTERNS, write_plots
    from hapticlab.sessions.discrepancy.report import json_ready, toml_snippet
    from hapticlab.sessions.discrepancy.settings import Settings
    from hapticlab.sessions.discrepancy.workflow import discrepancy

    registry = Registry()
    if not 0 <= args.min_gain < 100:
        raise UserError(f"--min-gain: a percentage in [0, 100), got {args.min_gain:g}")
    if not 0 <= args.min_structure <= 100:
        raise UserError(f"--min-structure: a percentage in [0, 100], got {args.min_structure:g}")
    settings = Settings(
        folds=args.folds,
        time_base=args.time_base,
        min_gain=args.min_gain / 100,
        min_structure_share=args.min_structure / 100,
    )
    if args.effects is not None:
        names = [n.strip() for n in args.effects.split(",") if n.strip()]
        for name in names:
            if name not in registry.names("effect"):
                raise UserError(f"--effects: unknown effect {name!r}; available: {', '.join(registry.names('effect'))}")
        settings.effects = names
    for item in args.set or []:
        key, sep, value = item.partition("=")
        effect, dot, option = key.strip().removeprefix("effects.").partition(".")
        if not sep or not dot or not option:
            raise UserError(f"--set {item!r}: expected EFFECT.OPTION=VALUE, e.g. bias_drift.order=2")
        if effect not in registry.names("effect"):
            raise UserError(
                f"--set {item!r}: unknown effect {effect!r}; available: {', '.join(registry.names('effect'))}"
            )
        settings.effect_options.setdefault(effect, {})[option] = parse_value(value, key)
    if args.folds < 3:
        raise UserError(f"--folds: at least 3, got {args.folds}")
    if Path(args.input).is_dir():
        if args.json or args.plots:
            raise UserError("--json and --plots are for one recording; a folder gives one table")
        return discrepancy_folder_table(args, settings)
    # check where the results go before the run, so a finished run is not lost to a bad path
    if args.json:
        check_output(args.json, args.force, label="--json", inputs=[args.input])
    if args.plots:
        check_plots_folder(args.plots, args.force, patterns=FIGURE_PATTERNS)
    with err.status(f"discrepancy: reading {Path(args.input).name}") as status:
        result = discrepancy(args.input, settings, registry, progress=lambda m: status.update(f"discrepancy: {m}"))
        print_discrepancy(result)
        # the JSON first: it is the result; the figures only show it
        if args.json:
            write_text(args.json, json.dumps(json_ready(result), indent=2) + "\n", args.force, label="--json")
            err.print(f"wrote {args.json}")
        if args.plots:
            status.update("discrepancy: plotting")
            try:
                for path in write_plots(result, args.plots, force=args.force):
                    err.print(f"wrote {path}")
            except OSError as exc:
                raise UserError(
                    f"--plots {args.plots}: cannot write the figures ({exc.strerror or exc})"
                    + (f"; the JSON is in {args.json}" if args.json else "")
                ) from exc
    sys.stdout.flush()
    print("\n# the named effects online: paste into a session file (the kalman estimator's options)")
    print(toml_snippet(result["estimator_options"]), flush=True)
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``hapticlab`` parser."""
    p = sub.add_parser(
        "discrepancy",
        help="find where simulation and measurement disagree, name the missing effects, add them, show the gap shrink",
    )
    p.add_argument(
        "input",
        help="CSV (import contract) or .mcap recording, or a folder: every .mcap under it, in parallel, one table",
    )
    p.add_argument("--json", default=None, help="write the result as JSON")
    p.add_argument("--plots", default=None, help="write the figures as PNG into this folder")
    p.add_argument("--effects", default=None, metavar="A,B", help="candidate effects (default: every registered one)")
    p.add_argument(
        "--set",
        action="append",
        metavar="EFFECT.OPTION=VALUE",
        help="an effect's option, e.g. --set bias_drift.order=2",
    )
    p.add_argument("--folds", type=int, default=10, help="contiguous folds of the held-out test (default 10)")
    p.add_argument(
        "--min-gain",
        type=float,
        default=1.0,
        metavar="PERCENT",
        help="held-out mean-square reduction that names an effect (default 1 %%)",
    )
    p.add_argument(
        "--min-structure",
        type=float,
        default=50.0,
        metavar="PERCENT",
        help="share of the structure the model leaves without it that a named effect must explain, "
        "or it is set aside (default 50 %%; 0: no structure test)",
    )
    p.add_argument(
        "--time-base",
        default="auto",
        choices=("auto", "seconds", "index"),
        help="what t is: auto (rows when t is 0, 1, 2, ...), seconds, or index (rows)",
    )
    add_folder_options(p)
    add_force(p)
    p.set_defaults(func=cmd_discrepancy)
