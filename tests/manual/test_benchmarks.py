"""Benchmark figures are data: the bench scripts write docs/benchmarks/*.json (commit, date,
machine), the manual renders the newest run of each table, and no page types a figure."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from app.manual.reference import DOCS, REPO, benchmark_files, benchmark_markdown, expand
from bench import results


def test_every_benchmark_file_names_its_script_and_when_and_where_each_run_was() -> None:
    files = benchmark_files()
    assert {"teacher", "keypoints", "closed_loop", "stream"} <= set(files)
    for name, data in files.items():
        assert (REPO / data["script"]).is_file(), name
        for run in data["runs"]:
            assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", run["date"]), name
            assert run["machine"] and run["command"] and run["tables"], name
            for table in run["tables"]:
                assert all(len(row) == len(table["columns"]) for row in table["rows"]), name


def test_the_benchmarks_page_has_no_figure_typed_by_hand() -> None:
    page = (DOCS / "benchmarks.md").read_text()
    prose = re.sub(r"```.*?```|`[^`]*`|<!--.*?-->", "", page, flags=re.S)
    assert not re.search(r"\d+(\.\d+)?\s*(ms|s|MB|fps|×|%)\b", prose)
    rendered = expand(page, lambda: {})
    assert "| ours (anchored groups, k=4) |" in rendered


def test_the_newest_run_of_a_table_is_the_one_shown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(results, "RESULTS", tmp_path)
    monkeypatch.setattr("app.manual.reference.BENCHMARKS", tmp_path)
    old = results.Table("case", ["case", "ms"], [["a", "9.0"]])
    results.record("bench/heatmap.py", [old])
    data = json.loads((tmp_path / "heatmap.json").read_text())
    data["runs"][0]["date"] = "2000-01-01"
    (tmp_path / "heatmap.json").write_text(json.dumps(data))
    results.record("bench/heatmap.py", [results.Table("case", ["case", "ms"], [["a", "1.0"]])])
    shown = benchmark_markdown("heatmap")
    assert "| a | 1.0 |" in shown and "9.0" not in shown
    assert len(json.loads((tmp_path / "heatmap.json").read_text())["runs"]) == 2


def test_a_script_s_printed_tables_are_recorded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(results, "RESULTS", tmp_path)
    with results.recorded("bench/stream.py"):
        print("a run\n| case | fps |\n|---|---:|\n| onnx | 120 |\n")
    assert "| onnx | 120 |" in capsys.readouterr().out
    (run,) = json.loads((tmp_path / "stream.json").read_text())["runs"]
    assert run["tables"][0]["rows"] == [["onnx", "120"]]
    assert run["tables"][0]["align"] == ["left", "right"]
