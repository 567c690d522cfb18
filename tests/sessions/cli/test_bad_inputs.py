"""The bad-input probe set: a few hundred bad inputs across the commands, each one line and exit status 2.

Every probe runs ``main([...])`` in-process and must return 2 with exactly one
line on stderr (``hapticlab <command>: error: ...``), no traceback and no
warning (the command line would print it on stderr), and leave the probe folder
exactly as it was: no file changed (an existing output keeps its bytes, even
with ``--force`` when the input is bad: outputs are written atomically), no
file created (no half-written output, no temporary left behind). Then each
writing command is shown to overwrite with ``--force``.

Inputs (generated here): CSV files breaking the contract in every column and
every way (non-numeric, NaN, infinite, empty, non-increasing ``t``, non-unit
quaternion, wrong field counts, wrong headers, binary, wrong encodings, a field
beyond the csv module's limit), MCAP files that are empty, text, truncated,
damaged or foreign (other topics, other fields, fields of the wrong shape or
type, messages that are not JSON, another encoding), numbers that defeat the
discrepancy workflow's solver; outputs that exist, are folders, lie under a
file, in a missing folder, in /proc or /sys (read-only even for root), or are
the input; option values out of range, for ``compensate``, ``replay``,
``recover``, ``discrepancy``, ``bench`` and ``run --set``.
"""

from __future__ import annotations

import gzip
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from helpers import cli_error, one_line_error, static_model_stream
from mcap.writer import Writer

from hapticlab.core.errors import OutputExistsError, UserError
from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.output import atomic_output, check_output, write_text
from hapticlab.sessions.recording import read_recording

HEADER = "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz"
COLUMNS = HEADER.split(",")
SENTINEL = b"an earlier result that must survive\n"


def good_rows(n: int = 60) -> list[list[str]]:
    block, _ = static_model_stream(n, seed=3, noise_force=0.1, noise_torque=0.01)
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    return [[repr(float(v)) for v in (k * 0.01, *block.force_S[k], *block.torque_S[k], *quat_BE[k])] for k in range(n)]


def csv_text(rows: list[list[str]], header: str = HEADER) -> str:
    return "\n".join([header, *(",".join(r) for r in rows)]) + "\n"


def with_cell(row: int, column: str, value: str):
    def make(rows):
        rows[row][COLUMNS.index(column)] = value
        return csv_text(rows)

    return make


def with_t(row: int, value: str):
    return with_cell(row, "t", value)


def with_quat(row: int, q: tuple[float, float, float, float]):
    def make(rows):
        rows[row][7:11] = [repr(v) for v in q]
        return csv_text(rows)

    return make


def with_fields(row: int, count: int):
    def make(rows):
        rows[row] = (rows[row] * 2)[:count]
        return csv_text(rows)

    return make


BAD_CSV = {
    **{f"text_in_{c}": with_cell(10, c, "abc") for c in COLUMNS},
    **{f"nan_in_{c}": with_cell(20, c, "nan") for c in COLUMNS},
    **{f"inf_in_{c}": with_cell(30, c, v) for c, v in (("fx", "inf"), ("tz", "-inf"), ("qy", "1e400"))},
    **{f"empty_{c}": with_cell(5, c, "") for c in ("t", "fy", "qw")},
    "t_repeats": with_t(1, "0.0"),
    "t_goes_back": with_t(30, "0.1"),
    "t_stops_at_the_end": with_t(59, "0.58"),
    "quat_norm_0.9": with_quat(4, (0.9, 0.0, 0.0, 0.0)),
    "quat_zero": with_quat(20, (0.0, 0.0, 0.0, 0.0)),
    "quat_norm_2": with_quat(59, (1.0, 1.0, 1.0, 1.0)),
    "row_with_12_fields": with_fields(3, 12),
    "row_with_10_fields": with_fields(40, 10),
    "row_with_1_field": with_fields(59, 1),
    "header_without_tz": lambda rows: csv_text([r[:10] for r in rows], HEADER.replace(",tz", "")),
    "header_without_t": lambda rows: csv_text([r[1:] for r in rows], HEADER[2:]),
    "header_of_another_tool": lambda rows: csv_text(rows, "time,Fx,Fy,Fz,Tx,Ty,Tz,w,x,y,z"),
    "no_header": lambda rows: csv_text(rows[1:], ",".join(rows[0])),
    "semicolons": lambda rows: csv_text(rows, HEADER).replace(",", ";"),
    "header_only": lambda rows: HEADER + "\n",
    "empty": lambda rows: "",
    "blank_lines_only": lambda rows: "\n\n  \n",
    "latin1_byte": lambda rows: csv_text(rows).encode()[:200] + b"\xe9t\xe9" + csv_text(rows).encode()[200:],
    "utf16": lambda rows: csv_text(rows).encode("utf-16"),
    "binary": lambda rows: np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes(),
    "gzipped": lambda rows: gzip.compress(csv_text(rows).encode()),
    "field_beyond_the_csv_limit": lambda rows: csv_text(rows) + "1" * 200_000 + "\n",
    "unclosed_quote": lambda rows: csv_text(rows[:30]) + '"' + ",".join(rows[30]) + "\n",
}
"""name -> rows -> file content: each breaks the CSV import contract once."""


def huge(rows):
    for r in rows:
        r[1:7] = [repr(float(v) * 1e300) for v in r[1:7]]
    return csv_text(rows)


def mcap_bytes(topics: dict[str, list[tuple[int, bytes]]], encoding: str = "json") -> bytes:
    """A valid MCAP file (another writer's: no hapticlab metadata) with these topics and raw messages."""
    import io

    buffer = io.BytesIO()
    writer = Writer(buffer)
    writer.start(profile="", library="another-tool")
    for topic, messages in topics.items():
        schema = writer.register_schema(
            name=topic, encoding="jsonschema" if encoding == "json" else "", data=b"{}" if encoding == "json" else b""
        )
        channel = writer.register_channel(topic=topic, message_encoding=encoding, schema_id=schema)
        for t, data in messages:
            writer.add_message(channel, t, data, t)
    writer.finish()
    return buffer.getvalue()


def messages(make, n: int = 50) -> list[tuple[int, bytes]]:
    return [(k * 1_000_000, json.dumps(make(k)).encode()) for k in range(n)]


WRENCH = lambda k: {"force_S": [1.0, 2.0, 3.0], "torque_S": [0.1, 0.2, 0.3], "seq": k, "status": 0}  # noqa: E731 (one-line factories)
POSE = lambda k: {"quat_BE": [1.0, 0.0, 0.0, 0.0], "p_BoEo_B": None}  # noqa: E731 (one-line factories)


def foreign(wrench=WRENCH, pose=POSE, extra=None, encoding="json") -> bytes:
    topics = {}
    if wrench is not None:
        topics["/sensor/wrench"] = messages(wrench)
    if pose is not None:
        topics["/kinematics/pose"] = messages(pose)
    topics.update(extra or {})
    return mcap_bytes(topics, encoding)


def damaged(good: bytes) -> bytes:
    import io

    from mcap.reader import make_reader

    summary = make_reader(io.BytesIO(good)).get_summary()
    index = max(summary.chunk_indexes, key=lambda c: c.chunk_length)
    data = bytearray(good)
    middle = index.chunk_start_offset + index.chunk_length // 2
    data[middle : middle + 8] = bytes(b ^ 0xFF for b in data[middle : middle + 8])
    return bytes(data)


BAD_MCAP = {
    "empty": lambda good: b"",
    "text": lambda good: b"these are my notes, not a recording\n",
    "a_csv": lambda good: (HEADER + "\n0,1,2,3,4,5,6,1,0,0,0\n").encode(),
    "magic_only": lambda good: good[:8],
    "cut_in_the_magic": lambda good: good[:5],
    "cut_in_half": lambda good: good[: len(good) // 2],
    "cut_before_the_end": lambda good: good[:-10],
    "damaged_chunk": damaged,
    "other_topics": lambda good: mcap_bytes({"/camera/info": messages(lambda k: {"width": 640})}),
    "no_poses": lambda good: foreign(pose=None),
    "no_wrench": lambda good: foreign(wrench=None),
    "wrench_of_another_tool": lambda good: foreign(wrench=lambda k: {"fx": 1.0, "fy": 2.0, "fz": 3.0}),
    "wrench_without_torque": lambda good: foreign(wrench=lambda k: {"force_S": [1.0, 2.0, 3.0]}),
    "force_of_two": lambda good: foreign(wrench=lambda k: {**WRENCH(k), "force_S": [1.0, 2.0]}),
    "force_as_text": lambda good: foreign(wrench=lambda k: {**WRENCH(k), "force_S": "1,2,3"}),
    "force_as_object": lambda good: foreign(wrench=lambda k: {**WRENCH(k), "force_S": {"x": 1}}),
    "status_as_text": lambda good: foreign(wrench=lambda k: {**WRENCH(k), "status": "ok"}),
    "seq_beyond_int64": lambda good: foreign(wrench=lambda k: {**WRENCH(k), "seq": 2**70}),
    "wrench_as_list": lambda good: foreign(wrench=lambda k: [1.0, 2.0, 3.0, 0.1, 0.2, 0.3]),
    "wrench_null": lambda good: foreign(wrench=lambda k: None),
    "quat_of_three": lambda good: foreign(pose=lambda k: {"quat_BE": [1.0, 0.0, 0.0]}),
    "quat_not_unit": lambda good: foreign(pose=lambda k: {"quat_BE": [2.0, 0.0, 0.0, 0.0]}),
    "pose_of_another_tool": lambda good: foreign(pose=lambda k: {"R_BE": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}),
    "position_of_two": lambda good: foreign(pose=lambda k: {"quat_BE": [1.0, 0, 0, 0], "p_BoEo_B": [1.0, 2.0]}),
    "not_json": lambda good: mcap_bytes(
        {"/sensor/wrench": [(k, b"{force_S: 1") for k in range(5)], "/kinematics/pose": messages(POSE)}
    ),
    "protobuf": lambda good: foreign(encoding="protobuf"),
}
"""name -> a good recording's bytes -> file content: unreadable or foreign recordings."""


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The probe folder: a good CSV and a tiny session recording, every bad input, existing outputs."""
    root = tmp_path_factory.mktemp("probes")
    rows = good_rows()
    (root / "good.csv").write_text(csv_text(rows))
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", "session.duration=0.3"])
    run_session(build_session(config), out=root / "good.mcap")
    good = (root / "good.mcap").read_bytes()
    for name, make in BAD_CSV.items():
        content = make([list(r) for r in rows])
        (root / f"{name}.csv").write_bytes(content if isinstance(content, bytes) else content.encode())
    (root / "huge_values.csv").write_text(huge([list(r) for r in rows]))
    for name, make in BAD_MCAP.items():
        (root / f"{name}.mcap").write_bytes(make(good))
    (root / "a_folder.csv").mkdir()
    (root / "a_folder.mcap").mkdir()
    (root / "review_folder").mkdir()
    (root / "review_folder" / "notes.mcap").write_text("not a recording\n")
    for name in ("existing.csv", "existing.json", "existing.mcap", "existing.html", "a_file"):
        (root / name).write_bytes(SENTINEL)
    (root / "figs").mkdir()
    for name in ("steps.png", "fig3_force_parameters.png"):
        (root / "figs" / name).write_bytes(SENTINEL)
    (root / "empty_folder").mkdir()
    for name in BAD_CSV:  # bench real on a folder holding only that file
        (root / f"bench_{name}").mkdir()
        (root / f"bench_{name}" / f"{name}.csv").write_bytes((root / f"{name}.csv").read_bytes())
    (root / "bench_one_bad").mkdir()
    (root / "bench_one_bad" / "bad.csv").write_text("t,fx\n0,1\n")
    (root / "bench_good").mkdir()
    (root / "bench_good" / "good.csv").write_text(csv_text(rows))
    (root / "with_an_extra_topic.mcap").write_bytes(foreign(extra={"/camera/info": messages(lambda k: {"w": 1})}))
    return root


def snapshot(root: Path) -> dict[str, tuple]:
    """Every path under ``root``: (size, mtime in ns, inode) for files ("dir" for folders), and the bytes' digest
    of the existing outputs (any write changes the first; the second shows the bytes are the same)."""
    out: dict[str, tuple] = {}
    for p in sorted(root.rglob("*")):
        if p.is_dir():
            out[str(p.relative_to(root))] = ("dir",)
            continue
        st = p.stat()
        digest = hashlib.sha1(p.read_bytes()).hexdigest() if p.name.startswith(("existing", "steps", "fig")) else ""
        out[str(p.relative_to(root))] = (st.st_size, st.st_mtime_ns, st.st_ino, digest)
    return out


def probes() -> list[tuple[str, list[str]]]:
    """(id, argv with {lab} for the probe folder): every bad input of every command."""
    out: list[tuple[str, list[str]]] = []
    csvs = [*BAD_CSV, "a_folder", "missing"]
    mcaps = [*BAD_MCAP, "a_folder", "missing"]
    for name in csvs:
        src = f"{{lab}}/{name}.csv"
        out.append((f"compensate-{name}.csv", ["compensate", src, "-o", "{lab}/existing.csv", "--force"]))
        if name in ("text_in_fx", "t_goes_back", "quat_zero", "header_only", "binary", "missing"):
            out.append(
                (
                    f"compensate-{name}.csv-params",
                    ["compensate", src, "-o", "{lab}/new.csv", "--params-out", "{lab}/existing.json", "--force"],
                )
            )
        out.append((f"discrepancy-{name}.csv", ["discrepancy", src, "--json", "{lab}/existing.json", "--force"]))
        out.append(
            (f"replay-{name}.csv", ["replay", src, "--estimator", "rls", "-o", "{lab}/existing.mcap", "--force"])
        )
    for name in BAD_CSV:
        out.append((f"bench-real-{name}.csv", ["bench", "real", f"{{lab}}/bench_{name}", "--json", "{lab}/new.json"]))
    for name in mcaps:
        src = f"{{lab}}/{name}.mcap"
        out.append((f"compensate-{name}.mcap", ["compensate", src, "-o", "{lab}/existing.csv", "--force"]))
        out.append((f"discrepancy-{name}.mcap", ["discrepancy", src, "--plots", "{lab}/figs", "--force"]))
        out.append(
            (f"replay-{name}.mcap", ["replay", src, "--estimator", "kalman", "-o", "{lab}/existing.mcap", "--force"])
        )
        out.append((f"review-{name}.mcap", ["review", src, "--html", "{lab}/existing.html", "--force"]))
    for name in ("empty", "text", "a_csv", "magic_only", "cut_in_the_magic", "a_folder", "missing"):
        out.append(
            (f"recover-{name}.mcap", ["recover", f"{{lab}}/{name}.mcap", "-o", "{lab}/existing.mcap", "--force"])
        )
    for name in ("binary", "gzipped", "utf16", "text_in_fx", "empty", "header_only"):
        out.append((f"recover-{name}.csv", ["recover", f"{{lab}}/{name}.csv", "-o", "{lab}/new.mcap"]))
    out.append(("discrepancy-huge_values.csv", ["discrepancy", "{lab}/huge_values.csv", "--json", "{lab}/new.json"]))
    out.append(
        (
            "replay-o-extra-topic",
            ["replay", "{lab}/with_an_extra_topic.mcap", "--estimator", "rls", "-o", "{lab}/new.mcap"],
        )
    )

    # outputs: existing without --force, a folder, under a file, in a missing folder, read-only places, the input
    writers = {
        "compensate-o": (["compensate", "{lab}/good.csv", "-o"], "csv"),
        "compensate-params-out": (["compensate", "{lab}/good.csv", "-o", "{lab}/new.csv", "--params-out"], "json"),
        "replay-o": (["replay", "{lab}/good.mcap", "--estimator", "batch", "-o"], "mcap"),
        "recover-o": (["recover", "{lab}/good.mcap", "-o"], "mcap"),
        "discrepancy-json": (["discrepancy", "{lab}/good.csv", "--json"], "json"),
        "bench-real-json": (["bench", "real", "{lab}/bench_good", "--json"], "json"),
        "bench-paper-json": (["bench", "paper", "--json"], "json"),
        "bench-estimators-json": (["bench", "estimators", "--json"], "json"),
        "bench-faults-json": (["bench", "faults", "--json"], "json"),
        "review-html": (["review", "{lab}/good.mcap", "--html"], "html"),
        "review-csv": (["review", "{lab}/review_folder", "--csv"], "csv"),
    }
    for label, (argv, ext) in writers.items():
        for kind, target in (
            ("exists", f"{{lab}}/existing.{ext}"),
            ("is-a-folder", "{lab}/figs"),
            ("under-a-file", f"{{lab}}/a_file/out.{ext}"),
            ("missing-folder", f"{{lab}}/nowhere/out.{ext}"),
            ("in-proc", f"/proc/out.{ext}"),
            ("in-sys", f"/sys/out.{ext}"),
        ):
            out.append((f"{label}-{kind}", [*argv, target]))
    for label, argv in (
        ("compensate-o", ["compensate", "{lab}/good.csv", "-o", "{lab}/good.csv"]),
        ("compensate-o-force", ["compensate", "{lab}/good.csv", "-o", "{lab}/good.csv", "--force"]),
        (
            "compensate-params-out",
            ["compensate", "{lab}/good.csv", "-o", "{lab}/new.csv", "--params-out", "{lab}/good.csv", "--force"],
        ),
        (
            "compensate-params-out-is-o",
            ["compensate", "{lab}/good.csv", "-o", "{lab}/new.csv", "--params-out", "{lab}/new.csv"],
        ),
        ("replay-o", ["replay", "{lab}/good.mcap", "--estimator", "rls", "-o", "{lab}/good.mcap", "--force"]),
        ("recover-o", ["recover", "{lab}/good.mcap", "-o", "{lab}/good.mcap", "--force"]),
        ("discrepancy-json", ["discrepancy", "{lab}/good.csv", "--json", "{lab}/good.csv", "--force"]),
    ):
        out.append((f"{label}-is-the-input", argv))
    for label, argv in (
        ("discrepancy", ["discrepancy", "{lab}/good.csv", "--plots"]),
        ("bench-paper", ["bench", "paper", "--plots"]),
    ):
        for kind, target in (
            ("holds-a-figure", "{lab}/figs"),
            ("is-a-file", "{lab}/a_file"),
            ("under-a-file", "{lab}/a_file/figs"),
            ("in-proc", "/proc/figs"),
            ("in-sys", "/sys/figs"),
        ):
            out.append((f"{label}-plots-{kind}", [*argv, target]))

    # option values
    compensate = ["compensate", "{lab}/good.csv", "-o", "{lab}/new.csv"]
    for option in (
        "--estimator=nope",
        "--set=bogus",
        "--set==2",
        "--set=estimator.gain=2",
        "--set=session.duration=2",
        "--set=estimator.name=nope",
        "--set=estimator.force_threshold=-1",
        "--set=estimator.force_threshold=nan",
        "--set=estimator.force_threshold=abc",
        "--set=estimator.P0=0",
        "--set=estimator.R=-1",
        "--set=estimator.epsilon=-1",
        "--set=estimator.seed=-1",
        "--set=estimator.seed=1.5",
    ):
        out.append((f"compensate-{option}", [*compensate, option]))
    kalman = [*compensate, "--estimator", "kalman"]
    for option in (
        "noise_force=-1",
        "noise_force=0",
        "noise_force=abc",
        "gating=bogus",
        "gate_probability=1.5",
        "convergence=never",
        "prior_force_std=0",
        "implementation=gpu",
        "effects=['wobble']",
        "mount_R_SE=[[1, 0], [0, 1]]",
        "warm_start='{lab}/missing.json'",
        "warm_start='{lab}/good.csv'",
        "time_lag_s=nan",
        "gain_force_S=[1, 2]",
    ):
        out.append((f"compensate-kalman-{option}", [*kalman, f"--set=estimator.{option}"]))
    batch = [*compensate, "--estimator", "batch"]
    for option in ("calibration_samples=-1", "min_rcond=-1", "force_threshold=abc"):
        out.append((f"compensate-batch-{option}", [*batch, f"--set=estimator.{option}"]))
    replay = ["replay", "{lab}/good.mcap"]
    for option in (
        ["--estimator", "nope"],
        ["--estimator", "rls", "--set", "bogus"],
        ["--estimator", "rls", "--set", "estimator.gain=2"],
    ):
        out.append((f"replay-{'-'.join(option)}", [*replay, *option]))
    discrepancy = ["discrepancy", "{lab}/good.csv"]
    for option in (
        ["--folds", "1"],
        ["--folds", "-3"],
        ["--min-gain", "100"],
        ["--min-gain", "-1"],
        ["--min-gain", "nan"],
        ["--min-structure", "101"],
        ["--min-structure", "nan"],
        ["--effects", "wobble"],
        ["--effects", "mount_rotation,wobble"],
        ["--set", "order=2"],
        ["--set", "wobble.order=2"],
        ["--set", "bias_drift.order=7"],
        ["--set", "bias_drift.ordr=2"],
        ["--set", "bias_drift.order"],
    ):
        out.append((f"discrepancy-{'-'.join(option)}", [*discrepancy, *option]))
    review = ["review", "{lab}/good.mcap"]
    for option in (
        ["--force-limit", "0"],
        ["--force-limit", "-1"],
        ["--force-limit", "nan"],
        ["--csv", "{lab}/new.csv"],
        ["--plots", "{lab}/figs", "--force-limit", "0"],
        ["--plots", "{lab}/a_file"],
    ):
        out.append((f"review-{'-'.join(option)}", [*review, *option]))
    for label, argv in (
        ("workers-0", ["review", "{lab}/review_folder", "--workers", "0"]),
        ("no-recordings", ["review", "{lab}/empty_folder"]),
        ("plots-of-a-folder", ["review", "{lab}/review_folder", "--plots", "{lab}/figs3"]),
    ):
        out.append((f"review-{label}", argv))
    for label, argv in (
        ("real-plots", ["bench", "real", "--plots", "{lab}/figs2"]),
        ("real-missing-folder", ["bench", "real", "{lab}/nowhere"]),
        ("real-a-file", ["bench", "real", "{lab}/good.csv"]),
        ("real-no-csv", ["bench", "real", "{lab}/empty_folder"]),
        ("real-one-bad-file", ["bench", "real", "{lab}/bench_one_bad"]),
        ("estimators-folder", ["bench", "estimators", "{lab}"]),
        ("faults-quick", ["bench", "faults", "--quick"]),
    ):
        out.append((f"bench-{label}", argv))

    # run --set: refused before the session starts (each would otherwise run 50 ms, simulated)
    run = ["run", "--duration", "0.05", "--set", "session.realtime=false", "--out", "{lab}/new.mcap"]
    for setting in (
        "shadows.rls.force_treshold=2",
        "estimator.noise_forse=2",
        "sesion.duration=2",
        "bogus",
        "=1",
        "session.loop_rate_hz=0",
        "session.loop_rate_hz=-1",
        "session.loop_rate_hz=nan",
        "session.loop_rate_hz=abc",
        "session.stale_timeout=-1",
        "session.stale_timeout=100",
        "haptic.max_force=-1",
        "haptic.max_force_rate=nan",
        "haptic.scale=abc",
        "sensor.name=nope",
        "kinematics.name=nope",
        "estimator.name=nope",
        "haptic.name=nope",
        "sensor.rate_hz=0",
        "kinematics.rate_hz=-5",
        "shadows.rls.force_threshold=-1",
        "shadows.rls.P0=abc",
        "estimator.noise_force=-1",
        "shadows.kalman={}",
        'shadows.x={name="nope"}',
        "shadows.y=3",
        "estimator.warm_start='{lab}/missing.json'",
        "estimator=3",
        "world.seed=abc",
        "world.tool.mass=-1",
        "world.tool.cog=[0, 0]",
        "world.sensor.gain_force=[[0.6, 0, 0], [0, 0, 0], [0, 0, 0]]",
        "world.motion.script=wiggle",
        "haptic.rotation_DB=[1, 2]",
        "teleop.scale=0",
        "session.recording_writer=disk",
    ):
        out.append((f"run-set-{setting}", [*run, "--set", setting]))
    for label, argv in (
        ("duration-negative", ["run", "--duration", "-1"]),
        ("duration-nan", ["run", "--duration", "nan"]),
        ("duration-a-year", ["run", "--duration", "3e7"]),
        ("session-missing", ["run", "{lab}/missing.toml"]),
        ("session-is-a-csv", ["run", "{lab}/good.csv"]),
        ("session-unknown-preset", ["run", "nosuchpreset"]),
    ):
        out.append((f"run-{label}", argv))

    # emulate: refused before serving (--duration: a probe that is wrongly accepted ends anyway)
    for device, options in (
        ("netft", ["--session", "{lab}/missing.toml"]),
        ("netft", ["--session", "{lab}/good.csv"]),
        ("netft", ["--seed", "-1"]),
        ("netft", ["--rate", "3000"]),
        ("netft", ["--rate", "-1"]),
        ("netft", ["--counts-per-force", "-1"]),
        ("netft", ["--counts-per-torque", "nan"]),
        ("netft", ["--fault", "explode"]),
        ("netft", ["--fault", "drop,start=-1"]),
        ("netft", ["--fault", "drop,duration=0"]),
        ("netft", ["--fault", "drop,every=0"]),
        ("netft", ["--fault", "drop,every=x"]),
        ("netft", ["--fault", "drop,when=1"]),
        ("netft", ["--fault", "status"]),
        ("netft", ["--address", "192.0.2.1"]),
        ("netft", ["--address", "192.0.2.1", "--allow-network"]),  # not an address of this machine
        ("ur", ["--session", "nosuchpreset"]),
        ("ur", ["--seed", "-1"]),
        ("ur", ["--encoder-noise", "1"]),
        ("ur", ["--encoder-noise", "nan"]),
        ("ur", ["--tcp-offset", "1,2"]),
        ("ur", ["--tcp-offset", "a,b,c,d,e,f"]),
        ("ur", ["--address", "192.0.2.1"]),
        ("ur", ["--address", "192.0.2.1", "--allow-network"]),  # not an address of this machine
        ("lab", ["--session", "{lab}/missing.toml"]),
        ("lab", ["--model", "ur7e"]),
        ("lab", ["--rate", "3000"]),
        ("lab", ["--ur-stall", "1"]),
        ("lab", ["--ur-stall=-1,1"]),
        ("lab", ["--netft-fault", "explode"]),
        ("lab", ["--netft", "192.0.2.1"]),
        ("lab", ["--netft", "192.0.2.1", "--allow-network"]),  # not an address of this machine
    ):
        out.append((f"emulate-{device}-{'-'.join(options)}", ["emulate", device, *options, "--duration", "0.5"]))
    return out


PROBES = probes()


GROUPS = sorted({argv[0] for _, argv in PROBES})


def test_there_are_a_few_hundred_probes():
    ids = [i for i, _ in PROBES]
    assert len(ids) == len(set(ids)) and len(PROBES) >= 350


@pytest.mark.parametrize("command", GROUPS)
def test_a_bad_input_is_one_line_and_nothing_is_lost(lab, capsys, command):
    """Every probe of one command (a loop, not one test each: ~25 ms a probe instead of ~100)."""
    failures = []
    for probe, argv in PROBES:
        if argv[0] != command:
            continue
        argv = [a.replace("{lab}", str(lab)) for a in argv]
        before = snapshot(lab)
        problem, line = cli_error(capsys, argv)
        if problem is None and snapshot(lab) != before:
            problem = "the probe folder changed"
        if problem is None and len(line) > 400:
            problem = "a line of more than 400 characters"
        if problem:
            failures.append(f"{probe}: {problem}: {line.strip()[-300:]}")
    assert not failures, "\n".join(failures)


def test_run_out_refuses_what_it_cannot_write(lab, capsys):
    """``run --out``: an existing recording is never overwritten, a folder or unwritable path refused (exit 2,
    the error last on stderr after the session's banner, which run prints before it opens the recording)."""
    for target in (lab / "existing.mcap", lab / "figs", Path("/proc/out.mcap"), lab / "a_file" / "out.mcap"):
        before = snapshot(lab)
        code = main(["run", "--duration", "0.05", "--set", "session.realtime=false", "--out", str(target)])
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err, err
        assert err.strip().splitlines()[-1].startswith("hapticlab run: error: ") and str(target.parent) in err, err
        assert snapshot(lab) == before


def test_bench_real_names_every_bad_file_and_goes_on(lab, tmp_path, capsys):
    """Beside a good file, each bad one is an error in the table (its own line, naming it), and the good one,
    and one whose numbers defeat the discrepancy workflow, are evaluated."""
    folder = tmp_path / "real"
    folder.mkdir()
    (folder / "good.csv").write_text(csv_text(good_rows(300)))
    for other in BAD_CSV:
        (folder / f"{other}.csv").write_bytes((lab / f"{other}.csv").read_bytes())
    (folder / "huge_values.csv").write_bytes((lab / "huge_values.csv").read_bytes())
    assert main(["bench", "real", str(folder), "--json", str(tmp_path / "r.json")]) == 0
    out = json.loads((tmp_path / "r.json").read_text())
    assert "error" not in out["good"] and out["good"]["estimators"]["rls"]["converged_force_at"] is not None
    for other in BAD_CSV:
        assert out[other]["error"].startswith(f"{other}.csv"), out[other]
    named = out["huge_values"]["estimators"]["kalman + named effects"]["error"]
    assert "huge_values.csv: numerical failure in the discrepancy workflow" in named
    assert "Traceback" not in capsys.readouterr().err


def test_force_overwrites_every_output(lab, tmp_path, capsys):
    """With --force an existing output is replaced (whole: it reads back), and no temporary file is left."""

    def existing(name: str) -> Path:
        path = tmp_path / name
        path.write_bytes(SENTINEL)
        return path

    good_csv, good_mcap = lab / "good.csv", lab / "good.mcap"
    out, params = existing("out.csv"), existing("p.json")
    assert main(["compensate", str(good_csv), "-o", str(out), "--params-out", str(params), "--force"]) == 0
    assert out.read_text().startswith("t,fx,fy,fz") and json.loads(params.read_text())["samples"] == 60
    replayed = existing("replayed.mcap")
    assert main(["replay", str(good_mcap), "--estimator", "batch", "-o", str(replayed), "--force"]) == 0
    assert "/estimator/batch" in read_recording(replayed).topics
    fixed = existing("fixed.mcap")
    assert main(["recover", str(good_mcap), "-o", str(fixed), "--force"]) == 0
    assert read_recording(fixed).topics.keys() == read_recording(good_mcap).topics.keys()
    report, figs = existing("d.json"), tmp_path / "figs"
    figs.mkdir()
    (figs / "steps.png").write_bytes(SENTINEL)
    (figs / "mine.png").write_bytes(SENTINEL)
    assert main(["discrepancy", str(good_csv), "--json", str(report), "--plots", str(figs), "--force"]) == 0
    assert "effects" in json.loads(report.read_text())
    assert (figs / "steps.png").read_bytes()[:4] == b"\x89PNG" and (figs / "mine.png").read_bytes() == SENTINEL
    real = existing("r.json")
    assert main(["bench", "real", str(lab / "bench_good"), "--json", str(real), "--force"]) == 0
    assert "good" in json.loads(real.read_text())
    assert not [p.name for p in tmp_path.rglob("*partial*")]
    capsys.readouterr()


def test_without_force_a_new_output_is_written_and_then_refused(lab, tmp_path, capsys):
    out = tmp_path / "out.csv"
    assert main(["compensate", str(lab / "good.csv"), "-o", str(out)]) == 0
    capsys.readouterr()
    written = out.read_bytes()
    line = one_line_error(capsys, ["compensate", str(lab / "good.csv"), "-o", str(out)])
    assert line == f"hapticlab compensate: error: -o {out}: already exists; --force overwrites it"
    assert out.read_bytes() == written


def test_atomic_output_keeps_the_old_file_when_writing_fails(tmp_path):
    target = tmp_path / "result.json"
    target.write_bytes(SENTINEL)
    # what raises is the whole atomic_output block (its body, then its exit): both statements are the test
    with pytest.raises(RuntimeError, match="half way"):  # noqa: PT012, SIM117
        with atomic_output(target, force=True) as tmp:
            tmp.write_text('{"half": ')
            raise RuntimeError("half way")
    assert target.read_bytes() == SENTINEL and sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]
    # a file that appears while the work runs is not overwritten either (without force)
    late = tmp_path / "late.json"
    with pytest.raises(OutputExistsError, match="--force overwrites it"):  # noqa: PT012, SIM117
        with atomic_output(late) as tmp:
            tmp.write_text("{}")
            late.write_bytes(SENTINEL)
    assert late.read_bytes() == SENTINEL and len(list(tmp_path.iterdir())) == 2
    # an OSError on the temporary file names the target, not the temporary
    with (
        pytest.raises(UserError, match=f"^--json {tmp_path / 'full.json'}: cannot write it"),
        atomic_output(tmp_path / "full.json", label="--json") as tmp,
    ):
        raise OSError(28, "No space left on device", str(tmp))
    write_text(tmp_path / "new.json", "{}\n")
    assert (tmp_path / "new.json").read_text() == "{}\n"


def test_check_output_names_what_is_wrong(tmp_path):
    (tmp_path / "in.csv").write_text("x")
    cases = {
        str(tmp_path): "is a folder; give a file name",
        str(tmp_path / "in.csv" / "o.csv"): f"folder {tmp_path / 'in.csv'} is not a folder",
        str(tmp_path / "no" / "o.csv"): f"folder {tmp_path / 'no'} does not exist",
        "/proc/o.csv": "cannot write in /proc",
        str(tmp_path / "in.csv"): "the output would overwrite the input",
    }
    for path, message in cases.items():
        with pytest.raises(UserError, match=message):
            check_output(path, force=True, label="-o", inputs=[tmp_path / "in.csv"])


def test_a_solver_failure_in_an_estimator_names_the_file_and_rows(tmp_path):
    """A LinAlgError inside an estimator is the input's (its numbers), not a traceback: file and rows named."""
    from hapticlab.sessions.offline.compensate import BLOCK, estimate_chunks
    from hapticlab.sessions.offline.numerics import NumericalError
    from hapticlab.sessions.recording.loader import iter_stream

    class Singular:
        calls = 0

        def update_block(self, block):
            Singular.calls += 1
            if Singular.calls == 3:
                raise np.linalg.LinAlgError("Singular matrix")
            from hapticlab.plugins.estimators.rls import RLSEstimator

            return RLSEstimator().update_block(block)

    (tmp_path / "log.csv").write_text(csv_text(good_rows(4000)))
    with pytest.raises(
        NumericalError,
        match=rf"^log.csv rows {2 * BLOCK + 1}-{3 * BLOCK}: numerical failure in "
        r"the estimator \(Singular matrix\)",
    ):
        list(estimate_chunks(iter_stream(tmp_path / "log.csv", rows=1500), Singular()))
