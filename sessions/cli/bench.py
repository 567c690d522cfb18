"""``hapticlab bench paper|estimators|real|faults|loop|teleop``: run one benchmark, print its tables, write its JSON.

The tables are printed by ``bench_paper_tables`` (the paper's) and ``bench_tables`` (the others).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hapticlab.core.errors import UserError
from hapticlab.sessions.cli.offline import add_force
from hapticlab.sessions.cli.render import err, finite_json
from hapticlab.sessions.output import check_output, check_plots_folder, write_text

TELEOP_FIGURE = "teleop_energy.png"
"""``bench teleop --plots``: force and energy of the worst case, with and without the passivity controller."""


def cmd_bench(args: argparse.Namespace) -> int:
    import json

    from hapticlab.sessions.cli.bench_paper_tables import print_paper_tables
    from hapticlab.sessions.cli.bench_tables import (
        print_estimators_table,
        print_faults_table,
        print_loop_tables,
        print_real_table,
        print_teleop_table,
    )

    if args.which != "paper" and (args.quick or args.all_estimators):
        raise UserError("--quick and --all-estimators go with 'bench paper'")
    if args.which not in ("paper", "teleop") and args.plots:
        raise UserError("--plots goes with 'bench paper' or 'bench teleop'")
    if args.which != "real" and args.folder:
        raise UserError(f"'bench {args.which}' takes no folder (got {args.folder!r}); did you mean 'bench real'?")
    # where the results go is checked before the benchmarks run, so a finished run is not lost to a bad path
    if args.json:
        check_output(args.json, args.force, label="--json")
    if args.plots:
        from hapticlab.sessions.bench.paper_plots import FIGURES

        patterns = FIGURES if args.which == "paper" else (TELEOP_FIGURE,)
        check_plots_folder(args.plots, args.force, patterns=patterns)
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
    elif args.which == "teleop":
        from hapticlab.sessions.bench.teleop import bench_teleop, write_plot

        with err.status("closing the teleoperation loop") as status:
            out, series = bench_teleop(progress=lambda m: status.update(f"bench teleop: {m}"))
        print_teleop_table(out)
        if args.plots:
            err.print(f"wrote {write_plot(series, Path(args.plots) / TELEOP_FIGURE, force=args.force)}")
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


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``hapticlab`` parser."""
    p = sub.add_parser(
        "bench",
        help="reproduce the paper's experiments (paper), measure the estimator family "
        "(estimators), evaluate real recordings (real) or inject faults into sessions (faults)",
    )
    p.add_argument(
        "which",
        choices=("paper", "estimators", "real", "faults", "loop", "teleop"),
        help="paper: simulated experiments; estimators: the estimator family's scenarios; real: CSV folder; "
        "faults: every injected fault through the run loop; loop: where a tick goes, "
        "per stage, and each estimator's µs per sample; teleop: the closed loop's stability and transparency "
        "per delay, passivity and tissue stiffness",
    )
    p.add_argument(
        "folder", nargs="?", default=None, help="with real: folder of CSV files (default ../shared/data/real)"
    )
    p.add_argument("--json", default=None, help="write every number as JSON")
    p.add_argument("--plots", default=None, help="with paper or teleop: write the figures as PNG into this folder")
    p.add_argument("--quick", action="store_true", help="with paper: a shorter run (smoke test)")
    p.add_argument("--all-estimators", action="store_true", help="with paper: repeat for every registered estimator")
    add_force(p)
    p.set_defaults(func=cmd_bench)
