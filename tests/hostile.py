"""The hostile inputs of the probe harness (tests/sessions/cli/test_probes.py).

:func:`build_lab` writes them into one folder (``{lab}`` in the table,
``probe_table.py``), :func:`prepare_out` the nodes of a probe's own output
folder (``{out}``). Inputs: missing, a folder, a FIFO, ``/dev/zero`` and
``/dev/urandom``, empty, random bytes (seeded), a sparse 4 GiB file (a whole
read is an unbounded read: the harness's memory limit ends it), a recording
cut at several offsets or with a corrupt chunk, session TOML files breaking
every rule once, corrupt warm-start JSON files; output nodes: a FIFO, a
symlink to a file or to nowhere, a read-only folder.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

SENTINEL = b"an earlier result that must survive\n"
SPARSE_BYTES = 4 << 30
"""bytes of the sparse file: twice the harness's address-space limit, so reading it whole cannot succeed."""


# --------------------------------------------------------------------------- inputs

COMMON = ("missing", "folder", "fifo", "dev-zero", "dev-urandom", "empty", "random", "sparse", "link-to-dev-zero")
"""Hostile inputs every file-reading command gets; the file is ``{lab}/<name>.<ext>`` (the devices by path)."""
NOT_IN_PROCESS = {"fifo", "dev-zero", "dev-urandom", "sparse", "link-to-dev-zero"}
"""Inputs that could hang or exhaust the test process if a guard were missing."""
FOLDER_COMMANDS = {"replay", "review", "discrepancy"}
"""Commands that take a folder of recordings as well (given ``{lab}/empty-folder.<ext>``, holding nothing)."""
CUTS = (8, 100, 1000, "1/4", "1/2", "3/4", -100, -1)
"""Offsets a good recording is cut at (bytes; a fraction of its length; from its end)."""


def cut_at(data: bytes, cut) -> bytes:
    if isinstance(cut, str):
        num, den = map(int, cut.split("/"))
        return data[: len(data) * num // den]
    return data[:cut]


def cut_name(cut) -> str:
    return f"cut-{cut}".replace("/", "of")


def corrupt_chunk(good: bytes) -> bytes:
    """The largest chunk's middle 64 bytes inverted (its CRC and zstd frame no longer hold)."""
    from mcap.reader import make_reader

    chunk = max(make_reader(io.BytesIO(good)).get_summary().chunk_indexes, key=lambda c: c.chunk_length)
    data = bytearray(good)
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle : middle + 64] = bytes(b ^ 0xFF for b in data[middle : middle + 64])
    return bytes(data)


def input_path(name: str, ext: str) -> str:
    return {"dev-zero": "/dev/zero", "dev-urandom": "/dev/urandom"}.get(name, f"{{lab}}/{name}.{ext}")


TOML_VALUES: dict[str, tuple[str, str]] = {
    **{
        f"duration-{v}": ("session.duration", v)
        for v in ("nan", "inf", "-inf", "-1.0", "0", "1e300", '"ten"', "true", "[1]")
    },
    **{f"loop-rate-{v}": ("session.loop_rate_hz", v) for v in ("nan", "inf", "0", "-1000", "1e12", '"fast"')},
    **{f"sensor-rate-{v}": ("sensor.rate_hz", v) for v in ("nan", "1e9", "-1", "inf")},
    **{f"kinematics-rate-{v}": ("kinematics.rate_hz", v) for v in ("inf", "0", "1e-300")},
    **{
        f"seed-{v}": ("world.seed", v)
        for v in ("-1", "1.5", "nan", "1e300", "18446744073709551616", "999999999999999999999999", '"seven"')
    },
    **{f"max-force-{v}": ("haptic.max_force", v) for v in ("inf", "-4.0", "nan", "1e300")},
    **{f"max-force-rate-{v}": ("haptic.max_force_rate", v) for v in ("-1", "inf")},
    **{f"segment-{v}": ("world.motion.segment_s", v) for v in ("0", "nan", "-1", "1e300")},
    **{f"tilt-{v}": ("world.motion.max_tilt_deg", v) for v in ("1e300", "nan")},
    **{f"tool-mass-{v}": ("world.tool.mass", v) for v in ("inf", "nan", "1e300")},
    "contacts-a-string": ("world.contacts", '"many"'),
    "contacts-numbers": ("world.contacts", "[1, 2]"),
    "contact-force-1e300": (
        "world.contacts",
        '[{kind = "indentation", start = 0.05, duration = 0.1, peak_force = 1e300}]',
    ),
    "contact-force-nan": ("world.contacts", '[{kind = "indentation", start = 0.05, duration = 0.1, peak_force = nan}]'),
    "contact-start-inf": ("world.contacts", '[{kind = "indentation", start = inf, duration = 0.1, peak_force = 1.0}]'),
    "unknown-key": ("session.bogus", "1"),
    "unknown-table": ("bogus", "{x = 1}"),
    "session-a-number": ("session", "3"),
    "estimator-name-a-number": ("estimator.name", "42"),
    "estimator-unknown": ("estimator.name", '"nope"'),
    "threshold-inf": ("shadows.rls.force_threshold", "inf"),
    "realtime-a-string": ("session.realtime", '"yes"'),
}
"""name -> (dotted key, TOML value) set in an otherwise good session file (quick and simulated)."""
RAW_TOML: dict[str, bytes] = {
    "not-utf8": '[session]\nname = "café"\n'.encode("latin-1"),
    "utf16": "[session]\nrealtime = false\n".encode("utf-16"),
    "not-toml": b"this is not toml = = =\n",
    "a-csv": b"t,fx,fy,fz\n0,1,2,3\n",
    "deep-arrays": b"[session]\nx = " + b"[" * 5000 + b"]" * 5000 + b"\n",
    "deep-inline-tables": b"x = " + b"{a = " * 3000 + b"1" + b"}" * 3000 + b"\n",
    "deep-dotted-key": b"[session]\nrealtime = false\n" + b".".join([b"a"] * 5000) + b" = 1\n",
    "deep-table-header": b"[" + b".".join([b"a"] * 5000) + b"]\nx = 1\n",
    "duplicate-key": b"[session]\nduration = 1.0\nduration = 2.0\n",
    "nul-byte": b"[session]\x00\n",
    "over-a-mebibyte": b"# " + b"x" * (1 << 20) + b"\n",
}
"""name -> the bytes of a session file that is no good TOML or nests without end."""
JSON_STATES: dict[str, object] = {
    "truncated": None,  # the good state, cut in half (built from it)
    "not-json": b"{this is not json",
    "a-list": b"[1, 2, 3]",
    "a-number": b"42",
    "deep": b"[" * 100_000 + b"]" * 100_000,
    "nan-everywhere": None,  # every number of the good state NaN
    "inf-everywhere": None,
    "strings-everywhere": None,  # every number of the good state a string
    "1e999": b'{"estimator": "kalman", "x": 1e999}',
    "huge-file": b'{"pad": "' + b"0" * (70 << 20) + b'"}',
}
"""name -> bytes of a corrupt ``<recording>.calibration.json`` (None: derived from the good one)."""


def _map_numbers(value, fn):
    if isinstance(value, dict):
        return {k: _map_numbers(v, fn) for k, v in value.items()}
    if isinstance(value, list):
        return [_map_numbers(v, fn) for v in value]
    if isinstance(value, float | int) and not isinstance(value, bool):
        return fn(value)
    return value


class Raw(str):
    """A value already in TOML syntax."""


def toml_value(v) -> str:
    if isinstance(v, Raw):
        return v
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(map(toml_value, v)) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    return repr(v)  # int or float (inf and nan are TOML too)


def toml_dump(table: dict, prefix: str = "") -> str:
    """``table`` as TOML text: scalars and arrays first, then one ``[header]`` per sub-table."""
    text = "".join(f"{k} = {toml_value(v)}\n" for k, v in table.items() if not isinstance(v, dict))
    for k, v in table.items():
        if isinstance(v, dict):
            text += f"\n[{prefix}{k}]\n" + toml_dump(v, f"{prefix}{k}.")
    return text


def toml_text(key: str, value: str) -> str:
    """The demo session made quick (simulated, 0.2 s) with ``key = value`` (TOML syntax) set in it."""
    from hapticlab.sessions.config import load_config

    config = load_config("demo")[0]
    config["session"].update(realtime=False, duration=0.2)
    *tables, leaf = key.split(".")
    node = config
    for name in tables:
        node = node.setdefault(name, {})
    node[leaf] = Raw(value)
    return toml_dump(config)


def build_lab(root: Path, good_mcap: Path, good_csv: Path, good_state: Path) -> None:
    """Write every hostile input into ``root`` beside the good ones (a recording, a CSV, a saved state)."""
    good = good_mcap.read_bytes()
    rng = np.random.default_rng(0)
    for ext in ("mcap", "csv", "toml", "json"):
        (root / f"folder.{ext}").mkdir()
        (root / f"empty.{ext}").write_bytes(b"")
        (root / f"random.{ext}").write_bytes(rng.integers(0, 256, 64 << 10, dtype=np.uint8).tobytes())
        for kind in ("fifo", "sparse", "link-to-dev-zero"):
            make_node(kind, root / f"{kind}.{ext}")
    for ext in ("mcap", "csv"):
        (root / f"empty-folder.{ext}").mkdir()
    for cut in CUTS:
        (root / f"{cut_name(cut)}.mcap").write_bytes(cut_at(good, cut))
    (root / "corrupt-chunk.mcap").write_bytes(corrupt_chunk(good))
    (root / "csv-named-mcap.mcap").write_bytes(good_csv.read_bytes())
    (root / "one-long-line.csv").write_bytes(b"t,fx" + b"0" * (2 << 20))  # 2 MiB, no newline
    for name, (key, value) in TOML_VALUES.items():
        (root / f"{name}.toml").write_text(toml_text(key, value))
    for name, data in RAW_TOML.items():
        (root / f"{name}.toml").write_bytes(data)
    state_text = good_state.read_bytes()
    state = json.loads(state_text)
    derived = {
        "truncated": state_text[: len(state_text) // 2],
        "nan-everywhere": json.dumps(_map_numbers(state, lambda v: float("nan"))).encode(),
        "inf-everywhere": json.dumps(_map_numbers(state, lambda v: float("inf"))).encode(),
        "strings-everywhere": json.dumps(_map_numbers(state, str)).encode(),
    }
    for name, data in JSON_STATES.items():
        (root / f"state-{name}.json").write_bytes(derived.get(name, data))
    (root / "a_file").write_bytes(SENTINEL)
    (root / "existing-target").write_bytes(SENTINEL)  # what the output symlinks point at
    for kind in ("fifo", "sparse", "link-to-dev-zero"):  # a folder of recordings or CSV files holding it
        folder = root / f"holds-{kind}"
        folder.mkdir()
        for ext in ("csv", "mcap"):
            make_node(kind, folder / f"{kind}.{ext}")


def make_node(kind: str, path: Path) -> None:
    """A FIFO, a sparse file of ``SPARSE_BYTES`` or a symlink to /dev/zero at ``path``."""
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "sparse":
        with open(path, "wb") as f:
            f.truncate(SPARSE_BYTES)
    else:
        path.symlink_to("/dev/zero")


def prepare_out(out: Path, lab: Path) -> None:
    """A probe's own folder: a FIFO, a symlink to ``{lab}/existing-target`` and a dangling one per output
    extension, and a read-only folder."""
    for ext in ("csv", "json", "mcap", "html", "png"):
        os.mkfifo(out / f"fifo.{ext}")
        (out / f"link.{ext}").symlink_to(lab / "existing-target")
        (out / f"dangling.{ext}").symlink_to(lab / "nowhere" / f"x.{ext}")
    (out / "read-only").mkdir(mode=0o555)
