"""The probe table of the harness (tests/sessions/cli/test_probes.py): every command line it tries.

A probe is one command line a new user might type, with ``{lab}`` for the
folder of hostile inputs (``hostile.build_lab``) and ``{out}`` for a fresh
folder of its own (``hostile.prepare_out``: a probe that is wrongly accepted
writes there, so it never changes what the next probe sees).
"""

from __future__ import annotations

from dataclasses import dataclass

from hostile import (
    COMMON,
    CUTS,
    FOLDER_COMMANDS,
    JSON_STATES,
    NOT_IN_PROCESS,
    RAW_TOML,
    TOML_VALUES,
    cut_name,
    input_path,
)

QUICK_RUN = ("--set", "session.realtime=false", "--duration", "0.2")
"""A simulated 0.2 s session: what ``run`` probes add unless they are about these settings."""


@dataclass(frozen=True)
class Probe:
    """One command line; ``names`` (with ``{lab}``/``{out}``) must appear in its error line when it exits 2
    (``cohort``: in its output);
    ``in_process``: quick and safe to run through ``main()`` in the test process (no FIFO, device, sparse
    file or worker process: those are for the process matrix, under a memory limit and a timeout)."""

    id: str
    argv: tuple[str, ...]
    names: str
    in_process: bool = True
    cohort: bool = False
    """A folder of files: a bad one is a row of the command's table naming it (exit 2), not its one line."""
    unwritable: bool = False
    """Its output folder is read-only (mode 0o555): nothing to probe as root (permission bits do not stop it)."""


READERS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "compensate": (("csv", "mcap"), ("compensate", "{in}", "-o", "{out}/new.csv")),
    "replay": (("mcap",), ("replay", "{in}", "--estimator", "rls", "-o", "{out}/new.mcap")),
    "recover": (("mcap",), ("recover", "{in}", "-o", "{out}/new.mcap")),
    "review": (("mcap",), ("review", "{in}", "--json", "{out}/new.json")),
    "discrepancy": (("csv", "mcap"), ("discrepancy", "{in}", "--json", "{out}/new.json")),
    "run": (("toml",), ("run", "{in}", "--out", "{out}/x.mcap", *QUICK_RUN)),
    "warm-start": (
        ("json",),
        (
            "compensate",
            "{lab}/good.csv",
            "-o",
            "{out}/new.csv",
            "--estimator",
            "kalman",
            "--set",
            "estimator.warm_start='{in}'",
        ),
    ),
    "emulate": (  # on ports of its own: probes wrongly accepted serve side by side
        ("toml",),
        ("emulate", "netft", "--session", "{in}", "--duration", "0.5", "--rdt-port", "0", "--http-port", "0"),
    ),
}
"""command -> (the extensions of the inputs it is given, its argv with ``{in}`` for the input)."""
WRITERS: dict[str, tuple[str, tuple[str, ...]]] = {
    "compensate-o": ("csv", ("compensate", "{lab}/good.csv", "-o", "{target}")),
    "compensate-params-out": (
        "json",
        ("compensate", "{lab}/good.csv", "-o", "{out}/new.csv", "--params-out", "{target}"),
    ),
    "replay-o": ("mcap", ("replay", "{lab}/good.mcap", "--estimator", "rls", "-o", "{target}")),
    "recover-o": ("mcap", ("recover", "{lab}/good.mcap", "-o", "{target}")),
    "review-html": ("html", ("review", "{lab}/good.mcap", "--html", "{target}")),
    "review-json": ("json", ("review", "{lab}/good.mcap", "--json", "{target}")),
    "discrepancy-json": ("json", ("discrepancy", "{lab}/good.csv", "--json", "{target}")),
    "run-out": ("mcap", ("run", "--out", "{target}", *QUICK_RUN)),
    "bench-real-json": ("json", ("bench", "real", "{lab}/bench-good", "--json", "{target}")),
}
"""writer -> (its output's extension, its argv with ``{target}`` for the output)."""
TARGETS: dict[str, tuple[str, tuple[str, ...]]] = {
    "exists": ("{lab}/existing.{ext}", ()),
    "is-a-folder": ("{lab}/folder.csv", ("--force",)),
    "is-a-fifo": ("{out}/fifo.{ext}", ()),
    "is-a-fifo-force": ("{out}/fifo.{ext}", ("--force",)),
    "is-dev-full-force": ("/dev/full", ("--force",)),
    "link-to-a-file": ("{out}/link.{ext}", ()),
    "link-to-a-file-force": ("{out}/link.{ext}", ("--force",)),
    "link-to-nowhere": ("{out}/dangling.{ext}", ()),
    "in-a-missing-folder": ("{out}/nowhere/new.{ext}", ()),
    "under-a-file": ("{lab}/a_file/new.{ext}", ()),
    "in-an-unwritable-folder": ("{out}/read-only/new.{ext}", ()),
}
"""target -> (the output path, extra options). ``{out}`` holds fresh nodes: fifo.*, link.* (to
``{lab}/existing-target``), dangling.* (to a missing file), read-only/ (mode 0o555)."""
CHEAP_WRITERS = {"compensate-o", "compensate-params-out", "recover-o", "review-json", "run-out"}
"""Writers whose good run is quick: given --force over a symlink they run to the end."""
BAD_SETS = (
    "session.duration=inf",
    "session.duration=1e300",
    "session.duration=1e-300",
    "world.seed=18446744073709551616",
    "world.seed=-1",
    "world.seed=nan",
    "haptic.max_force=inf",
    "sensor.rate_hz=1e12",
    "session.loop_rate_hz=1e-300",
    "shadows.rls.force_threshold=-inf",
    "world.contacts=[{kind='indentation', start=0.05, duration=0.1, peak_force=inf}]",
    "world.motion=[1, 2]",
    "estimator.warm_start=42",
    "estimator.warm_start=''",
    "a.b.c.d.e.f=1",
    "session.duration=" + "[" * 3000 + "]" * 3000,
)
"""``run --set`` values: infinite, absurd, tiny, beyond 64 bits, wrong types, nested without end."""


def probes() -> list[Probe]:
    """Every probe: inputs for each reading command, session files, warm starts, ``--set`` values, outputs."""
    out: list[Probe] = []
    for command, (exts, argv) in READERS.items():
        for ext in exts:
            names = list(COMMON)
            if ext == "mcap":
                names += [cut_name(c) for c in CUTS] + ["corrupt-chunk", "csv-named-mcap"]
            if ext == "csv":
                names += ["one-long-line"]
            if ext == "toml":
                names += [*TOML_VALUES, *RAW_TOML]
            if ext == "json":
                names += [f"state-{n}" for n in JSON_STATES]
            for name in names:
                path = input_path(name, ext)
                in_process, line = name not in NOT_IN_PROCESS and command != "emulate", argv
                if name == "folder" and command in FOLDER_COMMANDS:  # a cohort of none: one line naming the folder
                    path = path.replace("folder.", "empty-folder.")
                    line = (*argv[:2], *(("--estimator", "rls") if command == "replay" else ()), "--workers", "1")
                shown = path if name not in TOML_VALUES else TOML_VALUES[name][0].rpartition(".")[2]
                if ext == "toml" and name == "empty":  # a good TOML document: the session it lacks is named
                    shown = "[sensor]"
                out.append(
                    Probe(f"{command}-{name}.{ext}", tuple(a.replace("{in}", path) for a in line), shown, in_process)
                )
    out.append(
        Probe(
            "warm-start-good.json",
            tuple(a.replace("{in}", "{lab}/good.calibration.json") for a in READERS["warm-start"][1]),
            "",
        )
    )
    for kind in ("fifo", "sparse", "link-to-dev-zero"):
        folder = f"{{lab}}/holds-{kind}"
        out.append(Probe(f"bench-real-folder-holds-{kind}", ("bench", "real", folder), kind, False, cohort=True))
        out.append(Probe(f"review-folder-holds-{kind}", ("review", folder, "--workers", "1"), kind, False, cohort=True))
        out.append(
            Probe(
                f"replay-folder-holds-{kind}",
                ("replay", folder, "--estimator", "rls", "-o", "{out}/replayed", "--workers", "1"),
                kind,
                False,
                cohort=True,
            )
        )
    for setting in BAD_SETS:
        key = setting.partition("=")[0]
        out.append(
            Probe(
                f"run-set-{setting[:60].replace(' ', '')}",
                ("run", "--out", "{out}/x.mcap", *QUICK_RUN, "--set", setting),
                key,
            )
        )
    for duration in ("inf", "1e-300", "0", "-0.0"):
        argv = ("run", "--out", "{out}/x.mcap", "--set", "session.realtime=false", "--duration", duration)
        out.append(Probe(f"run-duration-{duration}", argv, "duration"))
    for writer, (ext, argv) in WRITERS.items():
        for target, (path, extra) in TARGETS.items():
            if target == "link-to-a-file-force" and writer not in CHEAP_WRITERS:
                continue
            if writer == "run-out" and extra:  # run has no --force: a recording is never overwritten
                if target.endswith("-force"):
                    continue
                extra = ()
            path = path.replace("{ext}", ext)
            in_process = "fifo" not in target and "dev" not in target
            line = tuple(a.replace("{target}", path) for a in argv) + extra
            out.append(Probe(f"{writer}-{target}", line, path, in_process, unwritable="unwritable" in target))
    for command in ("discrepancy", "review"):
        source = "{lab}/good.csv" if command == "discrepancy" else "{lab}/good.mcap"
        for target, path in (
            ("a-file", "{lab}/a_file"),
            ("a-fifo", "{out}/fifo.png"),
            ("under-a-file", "{lab}/a_file/figs"),
            ("a-device", "/dev/null"),
        ):
            out.append(
                Probe(
                    f"{command}-plots-{target}",
                    (command, source, "--plots", path),
                    path,
                    "fifo" not in path and "dev" not in path,
                )
            )
    return out
