"""Parquet in and out: a recording with the CSV contract's columns reads as the CSV does; compensate writes it."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from helpers import static_model_stream

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.sessions.offline.compensate import compensate
from hapticlab.sessions.recording.csvimport import OUTPUT_COLUMNS, REQUIRED, CsvError, read_csv
from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.parquetio import iter_parquet
from hapticlab.sessions.recording.stream import Stream

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")


def columns(n=400, seed=5, contact=slice(200, 260)) -> dict[str, np.ndarray]:
    """A static tool at random orientations, pushed for a while: the contract's columns and an extra one."""
    block, _ = static_model_stream(n, seed=seed, noise_force=0.1, noise_torque=0.01)
    block.force_S[contact] += [0.0, 1.0, 3.0]
    quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    values = [np.arange(n) * 1e-3, *block.force_S.T, *block.torque_S.T, *quat_BE.T]
    table = dict(zip(REQUIRED, values))
    table["temperature"] = np.full(n, 21.5)
    return table


def write_both(tmp_path, table) -> tuple:
    """The table as a Parquet file (row groups of 128 rows) and as a CSV with every digit."""
    pq.write_table(pa.table(table), tmp_path / "rec.parquet", row_group_size=128)
    names = list(table)
    rows = np.column_stack([table[c] for c in names])
    text = ",".join(names) + "\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in rows)
    (tmp_path / "rec.csv").write_text(text)
    return tmp_path / "rec.parquet", tmp_path / "rec.csv"


def test_a_parquet_recording_reads_as_the_same_csv(tmp_path):
    parquet, csv_path = write_both(tmp_path, columns())
    a, b = load_stream(parquet), read_csv(csv_path)
    parts = list(iter_parquet(parquet, rows=100))
    assert [len(p) for p in parts] == [100, 100, 100, 100]
    for x, y in ((a.t_s, b.t_s), (a.samples.force_S, b.samples.force_S), (a.samples.R_EB, b.samples.R_EB)):
        assert np.array_equal(x, y)
    assert np.array_equal(a.samples.seq, b.samples.seq) and np.array_equal(a.samples.t_ns, b.samples.t_ns)
    assert a.notes == ["rec.parquet: ignoring column(s) temperature"]


def test_compensate_reads_parquet_and_writes_parquet_with_the_csv_columns(tmp_path):
    parquet, csv_path = write_both(tmp_path, columns())
    compensate(parquet, tmp_path / "from_parquet.csv", "kalman")
    compensate(csv_path, tmp_path / "from_csv.csv", "kalman")
    assert (tmp_path / "from_parquet.csv").read_bytes() == (tmp_path / "from_csv.csv").read_bytes()
    compensate(csv_path, tmp_path / "out.parquet", "kalman")
    table = pq.read_table(tmp_path / "out.parquet")
    assert tuple(table.column_names) == OUTPUT_COLUMNS
    with (tmp_path / "from_csv.csv").open() as fh:
        rows = np.array(list(csv.reader(fh))[1:], dtype=float)
    got = np.column_stack([table.column(c).to_numpy() for c in OUTPUT_COLUMNS])
    assert np.allclose(got, rows, rtol=1e-8, atol=1e-12, equal_nan=True)  # the CSV keeps 9 digits
    assert got[:, 7].sum() > 30  # the push was seen as contact


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t: t.pop("qz"), r"rec.parquet: missing required column\(s\) qz \(required: t,fx,.*\)"),
        (lambda t: t.update(fy=t["fy"].astype(str)), r"rec.parquet: column 'fy' holds string, not numbers"),
        (lambda t: t["fx"].__setitem__(150, np.nan), r"rec.parquet row 151, column 'fx': nan is not a finite number"),
        (lambda t: t["t"].__setitem__(300, 0.1), r"rec.parquet row 301, column 't': 0.1 does not increase .*"),
        (
            lambda t: t["qw"].__setitem__(77, 2.0),
            r"rec.parquet row 78, columns qw,qx,qy,qz: not a unit quaternion \(norm .*\)",
        ),
    ],
)
def test_a_bad_parquet_recording_is_one_line_naming_the_row_and_column(tmp_path, change, message):
    table = columns()
    change(table)
    parquet = tmp_path / "rec.parquet"
    pq.write_table(pa.table(table), parquet)
    with pytest.raises(CsvError, match=f"^{message}$"):
        load_stream(parquet)


def test_a_null_cell_and_a_file_that_is_no_parquet_are_named(tmp_path):
    table = pa.table(columns())
    fz = pa.array(table.column("fz").to_numpy(), mask=np.arange(table.num_rows) == 9)
    pq.write_table(table.set_column(table.column_names.index("fz"), "fz", fz), tmp_path / "nulls.parquet")
    with pytest.raises(CsvError, match=r"^nulls.parquet row 10, column 'fz': null is not a finite number$"):
        load_stream(tmp_path / "nulls.parquet")
    (tmp_path / "text.parquet").write_text("t,fx\n0,1\n")
    with pytest.raises(CsvError, match=r"^text.parquet: not a Parquet file \(.*\)$"):
        load_stream(tmp_path / "text.parquet")


def test_rows_repeated_exactly_are_dropped_with_a_note(tmp_path):
    table = columns(n=300)
    doubled = {c: np.insert(v, [128, 129, 200], v[[127, 128, 199]]) for c, v in table.items()}  # 129: a batch's first
    pq.write_table(pa.table(doubled), tmp_path / "doubled.parquet", row_group_size=128)
    a = Stream.concatenate(list(iter_parquet(tmp_path / "doubled.parquet", rows=64)))
    assert len(a) == 300 and np.array_equal(a.t_s, table["t"])
    assert a.notes[1:] == [
        "doubled.parquet: dropped 2 row(s) that exactly repeat the row before them (row(s) 129, 131)",
        "doubled.parquet: dropped 1 row(s) that exactly repeat the row before them (row(s) 203)",
    ]
