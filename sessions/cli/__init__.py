"""The ``hapticlab`` command line.

Every command turns a bad input (config key, CSV row, file) into one line
naming the problem and exit status 2; nothing already recorded is lost.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.live import Live
from rich.table import Table

from ... import __version__
from ...core.plugins import KINDS, PluginError, Registry

err = Console(stderr=True)
out = Console()


class UserError(Exception):
    """An error the user can fix; printed as one line."""


def _user_errors() -> tuple[type[BaseException], ...]:
    from ..recording.csvimport import CsvError
    from ..recording import RecordingError

    return (PluginError, CsvError, RecordingError, UserError, ValueError, FileNotFoundError,
            FileExistsError)


def cmd_plugins(args: argparse.Namespace) -> int:
    registry = Registry()
    table = Table(title="hapticlab plugins")
    table.add_column("kind")
    table.add_column("name", style="bold")
    table.add_column("from")
    for entry in registry.entries():
        table.add_row(entry.kind, entry.name, entry.origin)
    out.print(table)
    empty = [k for k in KINDS if not registry.names(k)]
    if empty:
        out.print(f"no plugins yet for: {', '.join(empty)}")
    return 0


def _status_table(status) -> Table:
    table = Table.grid(padding=(0, 2))
    haptic = "[green]on[/]" if status.haptic_enabled else f"[yellow]off[/] ({status.reason})"
    table.add_row(
        f"t {status.elapsed_s:6.1f} s",
        f"{status.samples} samples @ {status.rate_hz:6.0f} Hz",
        "force " + ("[green]converged[/]" if status.converged_force else "[yellow]converging[/]"),
        "torque " + ("[green]converged[/]" if status.converged_torque else "[yellow]converging[/]"),
        "[red]CONTACT[/]" if status.contact else "free",
        f"haptic {haptic}",
        f"{status.events} events",
    )
    return table


def cmd_run(args: argparse.Namespace) -> int:
    from ..config import apply_overrides, load_config
    from ..live.loop import build_session, run_session

    config, origin = load_config(args.session)
    config = apply_overrides(config, args.set or [])
    session = build_session(config)
    duration = args.duration if args.duration is not None else session.settings.duration
    err.print(f"[bold]hapticlab run[/] {origin}: {duration:g} s, sensor {session.plugins['sensor']['name']}, "
              f"kinematics {session.plugins['kinematics']['name']}, estimator {session.estimator_name}, "
              f"haptic {session.plugins['haptic']['name']}  (Ctrl-C stops and keeps the recording)")
    if err.is_terminal:
        with Live(console=err, refresh_per_second=4, transient=False) as live:
            result = run_session(session, out=args.out, duration=duration,
                                 on_status=lambda s: live.update(_status_table(s)))
    else:
        result = run_session(session, out=args.out, duration=duration)
    table = Table(title=f"session {'interrupted' if result.interrupted else 'finished'}", show_header=False)
    table.add_row("recording", str(result.path))
    table.add_row("duration", f"{result.duration_s:.2f} s")
    table.add_row("wrench samples", str(result.samples))
    table.add_row("poses", str(result.poses))
    table.add_row("force converged at sample", str(result.first_converged_force))
    table.add_row("torque converged at sample", str(result.first_converged_torque))
    table.add_row("contact samples", str(result.contact_samples))
    table.add_row("haptic force on", f"{result.haptic_on_s:.2f} s")
    for key, value in result.params.items():
        table.add_row(key, "[" + ", ".join(f"{v:.4g}" for v in value) + "]")
    table.add_row("events", str(len(result.events)))
    err.print(table)
    print(result.path)
    return 0


def cmd_compensate(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from ..offline.compensate import compensate

    with Progress(console=err, transient=True, disable=not err.is_terminal) as progress:
        task = progress.add_task(f"compensating {Path(args.input).name}", total=None)
        result = compensate(
            args.input, args.output, estimator_name=args.estimator, overrides=args.set or [],
            params_out=args.params_out,
            progress=lambda done, total: progress.update(task, completed=done, total=total),
        )
    for note in result.notes:
        err.print(f"note: {note}")
    def fmt(values, unit):
        if all(v != v for v in values):  # NaN: that stage never converged
            return "n/a (not converged)"
        return "[" + ", ".join(f"{x:.4g}" for x in values) + f"] {unit}"

    err.print(f"{Path(args.input).name}: {result.rows} rows → {args.output} ({args.estimator}); "
              f"force converged at sample {result.first_converged_force}, torque at "
              f"{result.first_converged_torque}")
    err.print(f"RMS contact wrench on no-contact rows after convergence: force "
              f"{fmt(result.rms_force_S, 'N')}, torque {fmt(result.rms_torque_S, 'N·m')}")
    return 0


def _f(value, digits: int = 3) -> str:
    return "–" if value is None or value != value else f"{value:.{digits}f}"


def print_paper_tables(out: dict) -> None:
    """The paper's tables, ours beside the paper's numbers."""
    paper = out["paper"]
    conv = out["convergence"]
    out_console = out_table = Console(width=max(Console().width, 120))
    t = Table(title="Convergence (0-based sample index in the identification run; never = None)")
    for col in ("stage", "paper's ‖Δx‖ < 1e-3", "samples after force", "paper (samples)", "truth-based"):
        t.add_column(col, justify="right")
    t.add_row("force", str(conv["force_paper"]), "", str(paper["convergence"]["force_paper"]),
              str(conv["force_truth"]))
    t.add_row("torque", str(conv["torque_paper"]), str(conv["torque_paper_after_force"]),
              str(paper["convergence"]["torque_paper"]), str(conv["torque_truth"]))
    out_console.print(t)
    ident = out["identification"]
    t = Table(title=f"Identified parameters after {ident['samples']} samples")
    for col in ("parameter", "estimator", "batch fit, same samples", "truth"):
        t.add_column(col, justify="right")
    for key, scale, unit in (("gravity_force_B", 1, "N"), ("bias_force_S", 1, "N"), ("cog_S", 1000, "mm"),
                             ("bias_torque_S", 1, "N·m")):
        row = [", ".join(_f(v * scale, 3) for v in ident[src][key]) for src in ("params", "batch_fit", "truth")]
        t.add_row(f"{key} ({unit})", *row)
    out_console.print(t)
    for group, title, unit in (("force", "Table I: force error statistics", "N"),
                               ("torque", "Table II: torque error statistics", "N·m")):
        t = Table(title=f"{title} ({out['no_contact']['poses']} random poses, {unit})")
        for col in ("component", "condition", "MAE", "Max AE", "Std", "MAE comp.", "Std/noise", "paper MAE",
                    "paper Max AE", "paper Std", "paper comp."):
            t.add_column(col, justify="right")
        for axis, ours in out["no_contact"][group].items():
            ref = paper["no_contact"][group][axis]
            digits = 3
            t.add_row(axis, "before", _f(ours["mae_before"], digits), _f(ours["max_before"], digits),
                      _f(ours["std_before"], digits), f"{ours['mae_comp_pct']:.1f} %", "", _f(ref["mae_before"]),
                      _f(ref["max_before"]), _f(ref["std_before"]), f"{ref['mae_comp_pct']:.1f} %")
            t.add_row("", "after", _f(ours["mae_after"], digits), _f(ours["max_after"], digits),
                      _f(ours["std_after"], digits), "", _f(ours["std_after_over_noise"], 2), _f(ref["mae_after"]),
                      _f(ref["max_after"]),
                      _f(ref["std_after"]), "", end_section=True)
        out_table.print(t)
    t = Table(title="Table III: compensation error bounds over the random poses (±)")
    for col in ("component", "batch fit, held", "rls, frozen", "rls, running", "Yu et al. (paper)",
                "proposed (paper)"):
        t.add_column(col, justify="right")
    for axis in ("fx", "fy", "fz", "tx", "ty", "tz"):
        t.add_row(axis, _f(out["bounds"].get("batch", {}).get(axis)),
                  _f(out["bounds"].get("rls_frozen", {}).get(axis)), _f(out["bounds"]["rls"][axis]),
                  _f(paper["bounds"]["yu2021"][axis]), _f(paper["bounds"]["rls"][axis]))
    out_console.print(t)
    out_console.print("  batch fit and frozen rls: identified on the 20 s tour, then held; running rls keeps "
                      "learning during the poses, as the paper's does")
    ind = out["indentation"]
    out_console.print(
        f"Phantom indentation ({ind['contacts']} contacts): plateau detected {ind['detected_plateau_pct']:.1f} %, "
        f"false contact {ind['false_contact_pct']:.2f} %, RMS between contacts "
        f"[{', '.join(_f(v) for v in ind['rms_free'])}] N, error in contact "
        f"[{', '.join(_f(v) for v in ind['rms_error_in_contact'])}] N")
    t = Table(title="104 g reference mass (|contact force| against 1.02 N), one turn per speed")
    for col in ("deg/s", "MAE", "Max AE", "Std", "mean", "MAE, low noise", "Max AE, low noise", "Std, low noise"):
        t.add_column(col, justify="right")
    for speed in ("12", "30", "45", "72"):
        a, b = out["rotation_104g"][speed], out["rotation_104g_low_noise"][speed]
        t.add_row(speed, _f(a["mae"]), _f(a["max_ae"]), _f(a["std"]), _f(a["mean"]), _f(b["mae"]),
                  _f(b["max_ae"]), _f(b["std"]))
    out_console.print(t)
    out_console.print(
        f"  paper: MAE ≤ 0.04 N, Max AE 0.119 N at 72 deg/s, Std < 0.046 N; noise per axis "
        f"{out['rotation_104g']['noise_force']} N, low noise {out['rotation_104g_low_noise']['noise_force']} N")
    r = out["repeated_rows"]
    out_console.print(
        f"Repeated rows (40 poses × 5 identical rows, like the LWR4 logs): force 'converged' at row "
        f"{r['converged_force_at']}, then {r['refused_pct']:.1f} % of the (contact-free) rows refused as contact, "
        f"RMS [{', '.join(_f(v) for v in r['rms_force_S'])}] N")
    d = out["drift_contact"]
    out_console.print(
        f"Bias drift {d['drift_N_per_min']} N/min with an indentation every 10 s ({d['duration_s']:.0f} s): "
        f"{d['false_contact_pct']:.1f} % of no-contact samples refused as contact "
        f"({d['false_contact_last_30s_pct']:.1f} % over the last 30 s), "
        f"RMS without contact over the last 30 s [{', '.join(_f(v) for v in d['rms_free_last_30s'])}] N "
        f"(noise {d['noise_force']} N)")


def _finite_json(value):
    """NaN and infinities become null (JSON has no NaN)."""
    if isinstance(value, float) and value != value or value in (float("inf"), float("-inf")):
        return None
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_json(v) for v in value]
    return value


def cmd_bench(args: argparse.Namespace) -> int:
    import json

    if args.which != "paper" and (args.plots or args.quick or args.all_estimators):
        raise UserError("--plots, --quick and --all-estimators go with 'bench paper'")
    if args.which != "real" and args.folder:
        raise UserError(f"'bench {args.which}' takes no folder (got {args.folder!r}); did you mean 'bench real'?")
    if args.which == "paper":
        from ..bench.paper import bench_paper, write_plots

        with err.status("running the paper's experiments") as status:
            out, plots = bench_paper(quick=args.quick, all_estimators=args.all_estimators,
                                     progress=lambda m: status.update(f"bench paper: {m}"))
        print_paper_tables(out)
        if args.plots:
            for path in write_plots(plots, Path(args.plots)):
                err.print(f"wrote {path}")
    elif args.which == "estimators":
        from ..bench.family import bench_estimators

        with err.status("running the estimator family's scenarios") as status:
            out = bench_estimators(progress=lambda m: status.update(f"bench estimators: {m}"))
        print_estimators_table(out)
    else:
        from ..bench.real import bench_real, default_real_dir

        folder = Path(args.folder) if args.folder else default_real_dir()
        with err.status("evaluating real recordings") as status:
            out = bench_real(folder, progress=lambda m: status.update(f"bench real: {m}"))
        print_real_table(out)
    if args.json:
        Path(args.json).write_text(json.dumps(_finite_json(out), indent=2) + "\n", encoding="utf-8")
        err.print(f"wrote {args.json}")
    return 0


def print_estimators_table(out: dict) -> None:
    """One row per scenario and estimator variant: the numbers the issue's targets name."""
    t = Table(title="Estimator family (issue 4), simulated at 1 kHz, 0.12 N noise unless said")
    for col in ("scenario", "estimator", "RMS / noise fx, fy, fz", "other"):
        t.add_column(col, justify="right")

    def rms_rows(name: str, rows: dict, other: dict[str, str]) -> None:
        for k, (label, values) in enumerate(rows.items()):
            t.add_row(name if k == 0 else "", label, ", ".join(_f(v, 3) for v in values), other.get(label, ""),
                      end_section=k == len(rows) - 1)

    m = out["mount"]
    rms_rows("5° mount (last 15 s)", m["rms_over_noise_last_15s"],
             {"kalman mount_rotation": f"estimated within {m['mount_error_deg']:.3f}°"})
    i = out["inertia_tour"]
    rms_rows("inertia, random tour", i["rms_over_noise_last_15s"],
             {"rls": "inertial force RMS " + ", ".join(_f(v, 3) for v in i["inertial_force_rms_N"]) + " N"})
    r = out["rotation_104g"]
    for k, (label, n) in enumerate(r["estimators"].items()):
        t.add_row(f"104 g at {r['speed_deg_s']:.0f} deg/s (¼ noise)" if k == 0 else "", label, "",
                  f"Max AE {n['max_ae']:.3f} N per sample, {n['max_ae_10ms']:.3f} N over 10 ms; MAE {n['mae']:.3f} N",
                  end_section=k == len(r["estimators"]) - 1)
    rms_rows(f"kinematics {out['time_lag']['lag_s'] * 1000:.0f} ms late", out["time_lag"]["rms_over_noise_last_10s"],
             {})
    rms_rows("2 % calibration error", out["gain"]["rms_over_noise_last_10s"], {})
    p = out["payload"]
    if p.get("recognised_after_s") is None:
        t.add_row("100 g payload", "kalman", "", "not recognised")
    else:
        force, torque = p["force_flag_up_after_hang_s"], p["torque_flag_up_after_event_s"]
        t.add_row("100 g payload", "kalman", "",
                  f"recognised {p['recognised_after_s']:.3f} s after the hang; force flag up "
                  f"{'never' if force is None else f'{force:.3f} s after it'}; torque flag "
                  f"{'never' if torque is None else f'{torque:.3f} s after the event'}")
    Console(width=max(Console().width, 140)).print(t)


def print_real_table(out: dict) -> None:
    """One row per file and estimator."""
    t = Table(title="Real recordings: online RMS over every row after convergence, against the offline batch "
                    "fit over the same rows; and the ‖·‖ ratio over the file's second half")
    for col in ("file", "estimator", "force conv.", "torque conv.", "refused", "RMS fx, fy, fz (N)",
                "batch, same rows", "ratio per axis", "ratio ‖·‖", "2nd half"):
        t.add_column(col, justify="right")
    for name, entry in out.items():
        if "error" in entry:
            t.add_row(name, "", "", "", "", entry["error"], "", "", "", "", end_section=True)
            continue
        for k, (est_name, r) in enumerate(entry["estimators"].items()):
            if "error" in r:
                t.add_row(name if k == 0 else "", est_name, "", "", "", r["error"], "", "", "", "",
                          end_section=k == len(entry["estimators"]) - 1)
                continue
            if est_name.endswith("named effects"):
                est_name += " (" + (", ".join(entry.get("named_effects", [])) or "none") + ")"
            rms = ", ".join(_f(v) for v in r.get("rms_force_S", [])) or "never converged"
            batch = ", ".join(_f(v) for v in r.get("batch_rms_same_rows", [])) or "–"
            ratio = ", ".join(_f(v, 2) for v in r.get("ratio", [])) or "–"
            t.add_row(name if k == 0 else "", est_name, str(r["converged_force_at"]), str(r["converged_torque_at"]),
                      f"{r['refused_pct']:.1f} %", rms, batch, ratio, _f(r.get("ratio_norm"), 2),
                      _f(r.get("ratio_norm_second_half"), 2), end_section=k == len(entry["estimators"]) - 1)
    Console(width=max(Console().width, 140)).print(t)


def cmd_replay(args: argparse.Namespace) -> int:
    from ..offline.replay import replay

    with err.status(f"replaying {Path(args.recording).name} through {args.estimator}"):
        result = replay(args.recording, args.estimator, args.output, overrides=args.set or [])
    t = Table(title=f"{Path(args.recording).name}: {result['rows']} samples; no-contact samples after convergence")
    for col in ("estimator topic", "force conv.", "RMS fx, fy, fz (N)", "Max AE fx, fy, fz (N)",
                "contact agreement"):
        t.add_column(col, justify="right")
    for topic, r in result["comparison"].items():
        rms = ", ".join(_f(v) for v in r["rms_force_S"]) if r.get("rms_force_S") else "–"
        mx = ", ".join(_f(v) for v in r["max_ae_force_S"]) if r.get("max_ae_force_S") else "–"
        agree = f"{r['contact_agreement_pct']:.1f} %" if "contact_agreement_pct" in r else "–"
        name = f"{topic} (new)" if topic == result["topic"] else topic
        t.add_row(name, str(r["converged_force_at"]), rms, mx, agree)
    Console(width=max(Console().width, 120)).print(t)
    if args.output:
        err.print(f"wrote {args.output} (the original topics and {result['topic']})")
    return 0


def _vec(values, digits: int = 3) -> str:
    return "[" + ", ".join(_f(v, digits) for v in values) + "]"


def print_discrepancy(result: dict) -> None:
    """Candidate tables per round, the steps table, the comparison with the batch fit."""
    console = Console(width=max(Console().width, 140))
    for note in result["notes"]:
        err.print(f"note: {note}")
    noise = result["noise_estimate"]
    rate = f", {result['rate_hz']:.4g} samples/s" if result["rate_hz"] else ""
    console.print(
        f"[bold]{result['input']}[/]: {result['samples']} rows, {result['usable']} usable, "
        f"{result['gated']} set aside by the contact gate; t in {result['time_base']}{rate}; "
        f"noise estimate {_f(noise['force_S'][0], 4)} N, {_f(noise['torque_S'][0], 5)} N·m")
    for skipped in result["skipped"]:
        console.print(f"  not tested: [bold]{skipped['effect']}[/] ({skipped['reason']})")
    folds_rule = result["settings"]
    for i, rnd in enumerate(result["rounds"], start=1):
        need = f"{rnd[0]['wins_needed']} of {rnd[0]['folds']} folds" if rnd else "enough folds"
        t = Table(title=f"round {i}: candidates on held-out data (named if gain ≥ "
                        f"{100 * folds_rule['min_gain']:g} % and it improves ≥ {need})")
        for col in ("effect", "held-out gain", "folds improved", "t over folds", "verdict"):
            t.add_column(col, justify="right")
        named = result["steps"][i - 1]["effect"] if i <= len(result["steps"]) else None
        for e in sorted(rnd, key=lambda e: -e["heldout_gain"]):
            verdict = ("[green]named[/]" if e["effect"] == named else
                       "significant, smaller" if e["significant"] else "not significant")
            t.add_row(e["effect"], f"{100 * e['heldout_gain']:.2f} %", f"{e['folds_improved']}/{e['folds']}",
                      _f(e["t"], 1), verdict)
        console.print(t)
    t = Table(title="steps: RMS per axis before → after, on the same samples")
    for col in ("step", "effect", "evidence", "parameters", "force fx, fy, fz (N)", "torque tx, ty, tz (N·m)"):
        t.add_column(col, justify="right" if col != "parameters" else "left")
    t.add_row("0", "baseline", "", "the paper's model", _vec(result["baseline"]["rms_force_S"]),
              _vec(result["baseline"]["rms_torque_S"], 4))
    for i, step in enumerate(result["steps"], start=1):
        ev = step["evidence"]
        t.add_row(str(i), step["effect"], f"{100 * ev['heldout_gain']:.1f} %, {ev['folds_improved']}/{ev['folds']} folds",
                  step["summary"], f"{_vec(step['rms_force_before'])} → {_vec(step['rms_force_after'])}",
                  f"{_vec(step['rms_torque_before'], 4)} → {_vec(step['rms_torque_after'], 4)}")
    console.print(t)
    final, batch = result["final"], result["batch_fit"]
    ratio = np.linalg.norm(final["rms_force_S"]) / np.linalg.norm(batch["rms_force_S"])
    named = ", ".join(result["effects"]) or "nothing (no candidate is significant)"
    console.print(f"named: [bold]{named}[/]")
    console.print(f"final RMS force {_vec(final['rms_force_S'])} N, torque {_vec(final['rms_torque_S'], 4)} N·m; "
                  f"offline batch fit on the same samples {_vec(batch['rms_force_S'])} N, "
                  f"{_vec(batch['rms_torque_S'], 4)} N·m: force RMS norm "
                  + (f"{100 * (1 - ratio):.1f} % below the batch fit" if ratio <= 1 else
                     f"{100 * (ratio - 1):.1f} % above the batch fit"))


def cmd_discrepancy(args: argparse.Namespace) -> int:
    import json

    from ..config import parse_value
    from ..discrepancy.workflow import Settings, discrepancy, json_ready, toml_snippet

    registry = Registry()
    if not 0 <= args.min_gain < 100:
        raise UserError(f"--min-gain: a percentage in [0, 100), got {args.min_gain:g}")
    settings = Settings(folds=args.folds, time_base=args.time_base, min_gain=args.min_gain / 100)
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
            raise UserError(f"--set {item!r}: unknown effect {effect!r}; available: {', '.join(registry.names('effect'))}")
        settings.effect_options.setdefault(effect, {})[option] = parse_value(value)
    if args.folds < 3:
        raise UserError(f"--folds: at least 3, got {args.folds}")
    # check where the results go before the run, so a finished run is not lost to a bad path
    if args.json:
        target = Path(args.json)
        if target.is_dir():
            raise UserError(f"--json {args.json}: is a folder; give a file name")
        if not target.parent.is_dir():
            raise UserError(f"--json {args.json}: folder {target.parent} does not exist")
    if args.plots:
        target = Path(args.plots)
        if target.exists() and not target.is_dir():
            raise UserError(f"--plots {args.plots}: exists and is not a folder")
        parent = next((p for p in target.parents if p.exists()), None)
        if parent is not None and not parent.is_dir():
            raise UserError(f"--plots {args.plots}: {parent} is not a folder")
    with err.status(f"discrepancy: reading {Path(args.input).name}") as status:
        result = discrepancy(args.input, settings, registry,
                             progress=lambda m: status.update(f"discrepancy: {m}"))
        print_discrepancy(result)
        # the JSON first: it is the result; the figures only show it
        if args.json:
            try:
                Path(args.json).write_text(json.dumps(json_ready(result), indent=2) + "\n", encoding="utf-8")
            except OSError as exc:
                raise UserError(f"--json {args.json}: cannot write it ({exc.strerror or exc})") from exc
            err.print(f"wrote {args.json}")
        if args.plots:
            from ..discrepancy.plots import write_plots

            status.update("discrepancy: plotting")
            try:
                for path in write_plots(result, args.plots):
                    err.print(f"wrote {path}")
            except OSError as exc:
                raise UserError(f"--plots {args.plots}: cannot write the figures ({exc.strerror or exc})"
                                + (f"; the JSON is in {args.json}" if args.json else "")) from exc
    sys.stdout.flush()
    print("\n# the named effects online: paste into a session file (the kalman estimator's options)")
    print(toml_snippet(result["estimator_options"]), flush=True)
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from ..recording import recover

    counts = recover(args.broken, args.output)
    err.print(f"recovered {counts.get('messages', 0)} messages into {args.output}")
    for topic, n in sorted(counts.get("topics", {}).items()):
        err.print(f"  {topic}: {n}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hapticlab",
        description="Haptic teleoperation for robotic-surgery training: real-time F/T compensation, "
                    "recorded sessions.",
    )
    parser.add_argument("--version", action="version", version=f"hapticlab {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="run a session from a preset name or TOML file (default: demo)")
    p.add_argument("session", nargs="?", default=None, help="preset name or path to a .toml file")
    p.add_argument("--duration", type=float, default=None, help="seconds to run (overrides the config)")
    p.add_argument("--out", default=None, help="recording path (.mcap)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config value, e.g. --set estimator.name=batch")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plugins", help="list every registered plugin by kind, with where it came from")
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("compensate", help="run an estimator offline over a CSV or MCAP recording")
    p.add_argument("input", help="CSV (import contract) or .mcap recording")
    p.add_argument("-o", "--output", required=True, help="output CSV of the contact wrench per row")
    p.add_argument("--estimator", default="rls", help="estimator name (default: rls)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="estimator option, e.g. --set estimator.force_threshold=2")
    p.add_argument("--params-out", default=None, help="write the final parameters as JSON")
    p.set_defaults(func=cmd_compensate)

    p = sub.add_parser("bench", help="reproduce the paper's experiments (paper), measure the estimator family "
                       "(estimators) or evaluate real recordings (real)")
    p.add_argument("which", choices=("paper", "estimators", "real"),
                   help="paper: simulated experiments; estimators: issue 4's scenarios; real: CSV folder")
    p.add_argument("folder", nargs="?", default=None, help="with real: folder of CSV files "
                   "(default ../shared/data/real)")
    p.add_argument("--json", default=None, help="write every number as JSON")
    p.add_argument("--plots", default=None, help="with paper: write the figures as PNG into this folder")
    p.add_argument("--quick", action="store_true", help="with paper: a shorter run (smoke test)")
    p.add_argument("--all-estimators", action="store_true", help="with paper: repeat for every registered estimator")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("replay", help="re-run a recording through another estimator and compare")
    p.add_argument("recording", help="a session's .mcap")
    p.add_argument("--estimator", required=True, help="estimator name, e.g. batch")
    p.add_argument("-o", "--output", default=None, help="write a new .mcap with the replayed estimator added")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="estimator option, e.g. --set estimator.force_threshold=0.5")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("discrepancy", help="find where simulation and measurement disagree, name the missing "
                                          "effects, add them, show the gap shrink")
    p.add_argument("input", help="CSV (import contract) or .mcap recording")
    p.add_argument("--json", default=None, help="write the result as JSON")
    p.add_argument("--plots", default=None, help="write the figures as PNG into this folder")
    p.add_argument("--effects", default=None, metavar="A,B", help="candidate effects (default: every registered one)")
    p.add_argument("--set", action="append", metavar="EFFECT.OPTION=VALUE",
                   help="an effect's option, e.g. --set bias_drift.order=2")
    p.add_argument("--folds", type=int, default=10, help="contiguous folds of the held-out test (default 10)")
    p.add_argument("--min-gain", type=float, default=1.0, metavar="PERCENT",
                   help="held-out mean-square reduction that names an effect (default 1 %%)")
    p.add_argument("--time-base", default="auto", choices=("auto", "seconds", "index"),
                   help="what t is: auto (rows when t is 0, 1, 2, ...), seconds, or index (rows)")
    p.set_defaults(func=cmd_discrepancy)

    p = sub.add_parser("recover", help="salvage a recording whose writer died")
    p.add_argument("broken", help="the damaged .mcap")
    p.add_argument("-o", "--output", required=True, help="where to write the recovered .mcap")
    p.set_defaults(func=cmd_recover)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        err.print("interrupted")
        return 130
    except _user_errors() as exc:
        message = str(exc).strip().replace("\n", " ")
        print(f"hapticlab {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
