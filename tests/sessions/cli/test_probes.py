"""The probe harness of issue 39: every command that reads a file or takes an option, against hostile inputs.

The table is ``tests/probe_table.py``, the inputs ``tests/hostile.py``:
missing, a folder, a FIFO, devices, empty, random bytes, a sparse 4 GiB file,
recordings cut or corrupt, session TOML files and warm-start JSON files
breaking every rule, bad ``--set`` values; outputs that exist, are folders,
FIFOs, devices, symlinks, or lie where nothing can be written. Each probe must end (a timeout) with exit
status 0 or 2 (never 1, a signal or a MemoryError), print no traceback, say
an exit 2 in exactly one line ``hapticlab <command>: error: ...`` naming the
input, option or path at fault, and change no file that was there before
(bytes, size, mtime, inode; on exit 2 it creates none either).

Two tiers: the default runs the probes that cannot hang or exhaust this
process in-process through ``main()`` (one test per command, ~20 ms a probe);
the slow tier (``run_command``) runs the others (and a sample of those) in a fresh interpreter
limited to ``ADDRESS_SPACE_BYTES`` of address space (an unbounded read of a
device or a sparse file ends in a MemoryError there, not in a swapping
machine) with ``TIMEOUT_S`` to finish (a FIFO read would block for ever).
``test_bad_inputs.py`` holds the CSV and foreign-recording contract probes
(in-process); this harness adds the process-level guarantees and the
session, warm-start and output-node probes.
"""

from __future__ import annotations

import hashlib
import os
import resource
import shutil
import stat
import warnings
from pathlib import Path

import pytest
from helpers import static_model_stream
from hostile import SENTINEL, build_lab, prepare_out
from probe_table import Probe, probes
from processes import hapticlab_command

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session

AS_ROOT = "running as root: permission bits do not stop its writes, so a read-only folder probes nothing"
ADDRESS_SPACE_BYTES = 3 << 30
"""bytes of address space a probe's process may map (RLIMIT_AS): numba, numpy and the rest map ~1.2 GiB."""
TIMEOUT_S = 120.0
"""s a probe's process has to finish on a loaded 2-core machine (a good one takes 1-5 s)."""
IS_ROOT = os.geteuid() == 0
PROBES = probes()
BY_ID = {p.id: p for p in PROBES}
COMMANDS = sorted({p.argv[0] for p in PROBES if p.in_process})
IN_A_PROCESS = [p.id for p in PROBES if not p.in_process] + [
    next(p.id for p in PROBES if p.in_process and p.argv[0] == command) for command in COMMANDS
]
"""The slow tier's probes: those only a process can take (a hang, an unbounded read), and one of each
command's in-process ones (the exit status and stderr ``main()`` gives are the command line's): the other
in-process ones, ~2 s of interpreter start-up each, would add 8 minutes to the tier and test nothing new."""


def good_csv_text(n: int = 300) -> str:
    block, _ = static_model_stream(n, seed=3, noise_force=0.1, noise_torque=0.01)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    rows = [(k * 0.01, *block.force_S[k], *block.torque_S[k], *quat_BE[k]) for k in range(n)]
    return "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows)


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Path:
    """The folder of hostile inputs beside a good recording (a 1 s demo session), its saved state and a CSV."""
    root = tmp_path_factory.mktemp("lab")
    config = apply_overrides(load_config("demo")[0], ["session.realtime=false", "session.duration=1"])
    run_session(build_session(config), out=root / "good.mcap")
    (root / "good.csv").write_text(good_csv_text())
    (root / "bench-good").mkdir()
    shutil.copy(root / "good.csv", root / "bench-good" / "good.csv")
    for ext in ("csv", "json", "mcap", "html"):
        (root / f"existing.{ext}").write_bytes(SENTINEL)
    build_lab(root, root / "good.mcap", root / "good.csv", root / "good.calibration.json")
    return root


def snapshot(*roots: Path) -> dict[str, tuple]:
    """Every path under ``roots`` (symlinks not followed): its type, size, mtime (ns), inode, and the bytes'
    digest of a regular file under 1 MiB (the sparse files: their size and mtime)."""
    out: dict[str, tuple] = {}
    for root in roots:
        for p in sorted(root.rglob("*")):
            st = p.lstat()
            digest = ""
            if stat.S_ISREG(st.st_mode) and st.st_size < 1 << 20:
                digest = hashlib.sha1(p.read_bytes()).hexdigest()
            out[str(p)] = (stat.S_IFMT(st.st_mode), st.st_size, st.st_mtime_ns, st.st_ino, digest)
    return out


def judge(
    probe: Probe, code: int | str | None, err: str, before: dict, after: dict, lab: Path, out: Path, stdout: str = ""
) -> str | None:
    """What is wrong with a probe's outcome (exit status, stderr, stdout, the files before and after), or None."""
    if code not in (0, 2):
        return f"exit status {code}"
    if "Traceback" in err:
        return "a traceback"
    forced = "--force" in probe.argv  # a symlink given as the output with --force is replaced, its target kept
    changed = sorted(p for p in before if after.get(p) != before[p] and not (forced and before[p][0] == stat.S_IFLNK))
    if changed:
        return f"changed or removed {changed}"
    if code == 0:
        return None
    if probe.cohort:  # the folder's table names the bad file; what the good ones gave is kept
        return None if probe.names in stdout + err else f"the table does not name {probe.names!r}"
    created = sorted(set(after) - set(before))
    if created:
        return f"exit 2 but created {created}"
    lines = err.strip().splitlines()
    if len(lines) != 1:
        return f"{len(lines)} lines on stderr"
    if not lines[0].startswith(f"hapticlab {probe.argv[0]}: error: "):
        return "not the command's error line"
    names = probe.names.replace("{lab}", str(lab)).replace("{out}", str(out))
    if names not in lines[0] and Path(names).name not in lines[0]:  # the path, or the file's name
        return f"the line does not name {names!r}"
    return None


def argv_of(probe: Probe, lab: Path, out: Path) -> list[str]:
    return [a.replace("{lab}", str(lab)).replace("{out}", str(out)) for a in probe.argv]


def test_the_table_counts_its_probes():
    """Ids are unique and readable; the count is what the report says (printed with -s)."""
    ids = [p.id for p in PROBES]
    assert len(ids) == len(set(ids)) and all(" " not in i for i in ids)
    in_process = sum(p.in_process for p in PROBES)
    print(f"{len(PROBES)} probes over {len({p.argv[0] for p in PROBES})} commands, {in_process} in-process")
    assert len(PROBES) >= 300


@pytest.mark.parametrize("command", COMMANDS)
def test_probes_in_process(lab, tmp_path, capsys, command):
    """The probes of one command that cannot hang or exhaust this process, through ``main()``."""
    failures = []
    for k, probe in enumerate(p for p in PROBES if p.in_process and p.argv[0] == command):
        if probe.unwritable and IS_ROOT:  # (AS_ROOT; the process tier reports each as skipped)
            continue
        out = tmp_path / str(k)
        out.mkdir()
        prepare_out(out, lab)
        before = snapshot(lab, out)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            raised = ""
            try:
                code = main(argv_of(probe, lab, out))
            except SystemExit as exc:  # argparse
                code = exc.code
            except Exception as exc:  # a traceback the command line would print
                code, raised = 1, f"Traceback: {type(exc).__name__}: {exc}"
        captured = capsys.readouterr()
        err = captured.err + raised
        problem = judge(probe, code, err, before, snapshot(lab, out), lab, out, captured.out)
        if problem:
            failures.append(f"{probe.id}: {problem}: {err.strip()[-300:]}")
    assert not failures, f"{len(failures)} failed:\n" + "\n".join(failures)


def _limit_address_space() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_BYTES, ADDRESS_SPACE_BYTES))


@pytest.mark.parametrize("probe_id", IN_A_PROCESS)
def test_probe_in_a_process(lab, tmp_path, run_command, probe_id):
    """One probe in a fresh interpreter under a memory limit and a timeout: its real exit status and stderr."""
    probe = BY_ID[probe_id]
    if probe.unwritable and IS_ROOT:
        pytest.skip(AS_ROOT)
    out = tmp_path / "out"
    out.mkdir()
    prepare_out(out, lab)
    before = snapshot(lab, out)
    done = run_command(
        hapticlab_command(*argv_of(probe, lab, out)), probe.id, timeout=TIMEOUT_S, preexec_fn=_limit_address_space
    )
    code = done.returncode if done.returncode >= 0 else f"signal {-done.returncode}"
    problem = judge(probe, code, done.stderr, before, snapshot(lab, out), lab, out, done.stdout)
    assert problem is None, f"{problem}: {done.stderr.strip()[-2000:]}"
