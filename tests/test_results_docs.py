"""docs/results.md is what the generator makes of the JSON beside it, and the generator reads what the benches write.

Whether that JSON is current is a benchmark's question (it is measured, not tested); whether the page says
what the JSON says is this file's.
"""

from __future__ import annotations

import json
from pathlib import Path

from helpers import ROOT

from hapticlab.sessions.bench.report import DISCREPANCY_PREFIX, REAL, RESULTS, commands, main, render

PAGE = ROOT / "docs" / "results.md"
JSON = ROOT / "docs" / "results"


def test_docs_results_md_is_generated_from_the_json_beside_it():
    assert PAGE.read_text(encoding="utf-8") == render(JSON), (
        "docs/results.md is not what its JSON gives: run `python -m hapticlab.sessions.bench.report` "
        "from the checkout's root (never edit the page by hand)"
    )


def test_the_page_is_made_from_every_bench_and_each_real_recording():
    names = {path.stem for path in JSON.glob("*.json")}
    assert {"paper", "estimators", "real", "faults"} <= names
    recordings = sorted(json.loads((JSON / "real.json").read_text(encoding="utf-8")))
    assert {DISCREPANCY_PREFIX + name for name in recordings} <= names  # discrepancy on each real file
    # the commands the page lists (and --run runs) write exactly the JSON the page is made from
    written = set()
    for command in commands(RESULTS, REAL, recordings):
        written.add(Path(command[command.index("--json") + 1]).stem)
    assert written == names


def test_the_listed_commands_are_ones_the_command_line_takes():
    from hapticlab.sessions.cli import build_parser

    parser = build_parser()
    for command in commands(RESULTS, REAL, ["lwr4_2013_06_13"]):
        args = parser.parse_args(command)
        assert args.json.startswith(str(RESULTS)) and args.force


def test_every_number_comes_from_the_json(tmp_path):
    """A changed number in the JSON changes the page (no figure is typed into the generator)."""
    results = tmp_path / "results"
    results.mkdir()
    for path in JSON.glob("*.json"):
        (results / path.name).write_text(path.read_text(encoding="utf-8"), encoding="utf-8")
    before = render(results)
    paper = json.loads((results / "paper.json").read_text(encoding="utf-8"))
    paper["convergence"]["force_truth"] = 123456
    paper["no_contact"]["force"]["fx"]["std_after_over_noise"] = 9.87
    (results / "paper.json").write_text(json.dumps(paper), encoding="utf-8")
    after = render(results)
    assert "123456" not in before and "123456" in after and "9.87" in after


def test_the_command_writes_the_page(tmp_path):
    out = tmp_path / "results.md"
    assert main(["--results", str(JSON), "--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == PAGE.read_text(encoding="utf-8")
