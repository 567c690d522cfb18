"""A cohort's rows, CSV, Parquet file, learning curves and page (rows built here, no recording needed); the
page in headless Chromium at 1400 and 400 px, nothing cut off. The whole command on recordings is in
test_review.py (a cohort on a Dask cluster)."""

from __future__ import annotations

import csv
import io
import shutil
import sys
from html.parser import HTMLParser
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import chromium_fit

from hapticlab.core.types import Event
from hapticlab.sessions.cli import main
from hapticlab.sessions.output import OutputExistsError
from hapticlab.sessions.review import learning
from hapticlab.sessions.review.cohort import COLUMNS, csv_text, numbered, write_parquet
from hapticlab.sessions.review.cohort_page import cohort_page
from hapticlab.sessions.review.session import parameters_known_s
from hapticlab.sessions.review.skill_names import KEYS, METRICS


def cohort_rows(seed: int = 3) -> list[dict]:
    """Two tasks, five trainees with 1-5 sessions each (dates shuffled), two sessions without a trainee, one
    without a task; every metric known but some task times (None), long recording paths."""
    rng = np.random.default_rng(seed)
    rows = []
    for task, trainees in (("palpation", ("T01", "T02", "T03", "T04")), ("suturing", ("T01", "T05"))):
        for trainee in trainees:
            for k in range(int(rng.integers(1, 6))):
                row = {
                    "recording": f"autumn-cohort-of-the-skills-lab/{trainee}/{task}_{k}_2026-12-0{k + 1}.mcap",
                    "trainee": trainee,
                    "task": task,
                    "date": f"2026-12-0{k + 1}T10:{int(rng.integers(10, 60))}:00+00:00",
                    "duration_s": 60.0 + k,
                    "contacts": 3,
                    "force_limit_N": 3.0,
                    "estimator": "kalman",
                    "parameters_known_s": 2.337,
                    "lost_samples": 0,
                    "faults": int(k == 1),
                    "complete": k != 3,
                }
                row.update({key: round(float(rng.uniform(0, 100)), 3) for key in KEYS})
                row["excess_force_events"] = int(rng.integers(0, 6))
                row["task_time_s"] = None if k == 2 else row["task_time_s"]
                rows.append(row)
    rows.append({"recording": "anon.mcap", "trainee": "", "task": "palpation", "date": "2026-12-02T09:00:00"})
    rows.append({"recording": "anon2.mcap", "trainee": "", "task": "", "date": "2026-12-03", "peak_force_N": 4.0})
    rng.shuffle(rows)  # the order workers finish in
    return rows


class Tables(HTMLParser):
    """Every table of a page: id → rows of cell texts (the header first)."""

    def __init__(self, page: str):
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self.current: list[list[str]] | None = None
        self.cell: list[str] | None = None
        self.feed(page)

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.current = self.tables.setdefault(dict(attrs).get("id") or f"table-{len(self.tables)}", [])
        elif tag == "tr" and self.current is not None:
            self.current.append([])
        elif tag in ("td", "th"):
            self.cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self.current is not None and self.cell is not None:
            self.current[-1].append("".join(self.cell).strip())
            self.cell = None
        elif tag == "table":
            self.current = None

    def handle_data(self, data):
        if self.cell is not None:
            self.cell.append(data)


def test_sessions_are_numbered_per_trainee_and_task_in_date_order_and_the_unnamed_kept_apart():
    rows = numbered(cohort_rows())
    for trainee, task in {(r["trainee"], r["task"]) for r in rows}:
        mine = [r for r in rows if (r["trainee"], r["task"]) == (trainee, task)]
        assert [r["session"] for r in mine] == list(range(1, len(mine) + 1))  # in the cohort's order too
        assert [r["date"] for r in mine] == sorted(r["date"] for r in mine)
    assert [(r["task"], r["trainee"]) for r in rows] == sorted(
        ((r["task"], r["trainee"]) for r in rows), key=lambda tt: (not tt[0], tt[0], not tt[1], tt[1])
    )  # task, then trainee; the unnamed after the named, the session without a task last
    assert (rows[-1]["recording"], rows[-1]["session"]) == ("anon2.mcap", 1)
    page = cohort_page(rows, "cohort")
    trainees = {r["trainee"] for r in rows if r["trainee"]}
    assert len(trainees) == 5 and f"{len(rows)} session(s), 5 trainee(s), 3 task(s); 2 session(s) without" in page


def test_the_csv_and_the_page_have_the_same_rows_in_the_same_order_and_metrics_with_units():
    rows = numbered(cohort_rows())
    table = list(csv.DictReader(io.StringIO(csv_text(rows))))
    header = next(csv.reader(io.StringIO(csv_text(rows))))
    assert header == list(COLUMNS) and set(KEYS) <= set(header) and "converged_s" not in header
    assert [int(r["session"]) for r in table] == [r["session"] for r in rows]
    assert table[0]["task_time_s"] != "" and any(r["task_time_s"] == "" for r in table)  # None: an empty cell
    tables = Tables(cohort_page(rows, "cohort")).tables
    sessions = tables["cohort"]
    assert sessions[0][:4] == ["trainee", "task", "session", "date"] and "recording" in sessions[0]
    assert [(s[0], s[1], s[2], s[-1]) for s in sessions[1:]] == [
        (r["trainee"] or "(no trainee)", r["task"] or "(no task)", r["session"], r["recording"]) for r in table
    ]
    shown = []  # the tasks' metric tables, one after the other: the CSV's rows again
    for n in (1, 2, 3):
        forces, motion = tables[f"task-{n}-forces"], tables[f"task-{n}-motion"]
        assert [m[:2] for m in forces[1:]] == [m[:2] for m in motion[1:]]
        shown += [m[:2] for m in forces[1:]]
        words = forces[0][2:] + motion[0][2:]
        assert sorted(words) == sorted(f"{w} ({u})" if u else w for _, w, u in METRICS)  # words, with units
    assert shown == [[r["trainee"] or "(no trainee)", r["session"]] for r in table]
    peak = tables["task-1-forces"][1][2]
    assert peak == f"{float(table[0]['peak_force_N']):.2f}"


def test_the_parquet_file_reads_back_as_the_csv(tmp_path):
    import pyarrow.parquet as pq

    rows = numbered(cohort_rows())
    path = write_parquet(tmp_path / "cohort.parquet", rows)
    back = pq.read_table(path)
    table = list(csv.DictReader(io.StringIO(csv_text(rows))))
    assert back.column_names == list(COLUMNS) and back.num_rows == len(table)
    assert str(back.schema.field("session").type) == "int64" and str(back.schema.field("sparc").type) == "double"
    for row, got in zip(table, back.to_pylist()):
        for column in COLUMNS:
            value = got[column]
            assert ("" if value is None else str(value)) == row[column], column
    with pytest.raises(OutputExistsError):
        write_parquet(tmp_path / "cohort.parquet", rows)
    write_parquet(tmp_path / "cohort.parquet", rows[:3], force=True)
    assert pq.read_table(tmp_path / "cohort.parquet").num_rows == 3


def test_parquet_without_pyarrow_or_over_a_file_is_one_line_and_status_2(tmp_path, capsys, monkeypatch):
    folder = tmp_path / "cohort"
    folder.mkdir()
    (tmp_path / "old.parquet").write_bytes(b"PAR1")
    assert main(["review", str(folder), "--parquet", str(tmp_path / "old.parquet")]) == 2
    assert "already exists" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow raises ImportError
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    assert main(["review", str(folder), "--parquet", str(tmp_path / "new.parquet")]) == 2
    err = capsys.readouterr().err
    assert "pip install 'hapticlab[parquet]'" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "new.parquet").exists()
    (tmp_path / "one.mcap").write_bytes(b"")
    assert main(["review", str(tmp_path / "one.mcap"), "--parquet", str(tmp_path / "new.parquet")]) == 2
    assert "--parquet: a cohort's table" in capsys.readouterr().err  # one session has no cohort table


def test_parameters_known_is_the_gates_event_not_the_estimators_first_flag():
    review = SimpleNamespace(
        events=[
            Event(5_000_000, "converged", "kalman force stage converged"),
            Event(2_337_000_000, "parameters_known", ""),
        ],
        t_s=lambda t_ns: t_ns / 1e9,
    )
    assert parameters_known_s(review) == 2.337  # the old converged_s read the 0.005 s flag
    review.events = review.events[:1]
    assert parameters_known_s(review) is None


def test_the_band_is_the_named_trainees_percentiles_per_session():
    rows = [
        {"trainee": "A", "session": 1, "peak_force_N": 1.0},
        {"trainee": "B", "session": 1, "peak_force_N": 2.0},
        {"trainee": "C", "session": 1, "peak_force_N": 3.0},
        {"trainee": "", "session": 1, "peak_force_N": 100.0},  # no trainee: not the cohort
        {"trainee": "A", "session": 2, "peak_force_N": 5.0},  # one trainee: no band
        {"trainee": "B", "session": 2, "peak_force_N": None},
    ]
    n, p = learning.band(rows, "peak_force_N")
    assert list(n) == [1, 2]
    np.testing.assert_allclose(p[0], [1.5, 2.0, 2.5])
    assert np.isnan(p[1]).all()


def test_learning_curves_have_a_panel_per_task_and_metric_and_whole_sessions_on_x():
    rows = numbered(cohort_rows())
    one = numbered([{**r, "trainee": "X", "task": "biopsy"} for r in cohort_rows()[:1]])  # one session only
    figures = learning.learning_figures(rows + one)
    assert len(figures) == 2  # 4 tasks: 3 in the first figure, 1 in the second
    first, second = figures
    assert len(first.axes) == 3 * len(learning.CURVES) and len(second.axes) == len(learning.CURVES)
    assert [ax.get_title() for ax in first.axes[:3]] == ["biopsy", "palpation", "suturing"]  # the rows' order
    assert second.axes[0].get_title() == "(no task)"
    for ax in first.axes + second.axes:
        ticks = ax.get_xticks()
        assert len(ticks) and np.array_equal(ticks, np.round(ticks)) and ticks.min() >= 1, ax.get_title()
    biopsy = first.axes[-3]  # one session: one tick, not 0.96-1.04
    assert list(biopsy.get_xticks()) == [1] and biopsy.get_xlim() == (0.5, 1.5)
    labels = [t.get_text() for t in first.legends[0].get_texts()]
    assert labels == ["cohort 25–75 %", "cohort median", "T01", "T02", "T03", "T04", "T05", "X", "(no trainee)"]
    assert learning.learning_pngs([{**r, "task_score": None} for r in one]) != []  # peak force still drawn
    assert learning.learning_pngs([{"trainee": "X", "task": "t", "session": 1}]) == []  # nothing measured


def test_the_cohort_page_fits_1400_and_400_px_in_headless_chromium(tmp_path, run_command):
    """Nothing cut off: the page never wider than the window, every heading, paragraph, image and table box
    inside it; at 1400 px every table fits whole, at 400 px a table may scroll inside its own box."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "Debian's chromium is needed (README: apt-get install chromium)"
    rows = numbered(cohort_rows())
    page = cohort_page(
        rows,
        "Cohort review: /srv/archive/autumn-cohort-2026-palpation-and-suturing/",
        [("broken/recording.mcap", "not a recording: no /aligned/sample or /estimator/<name> topic")],
    )
    for width in (1400, 400):
        check = chromium_fit(chromium, page, width, tmp_path, run_command)
        if width == 1400:
            assert check["scrolled"] == [], check  # every table whole in a desktop window
