"""Benchmarks write their tables as data: each run of a script adds one entry, with the commit,
the date and the machine, to ``docs/benchmarks/<script>.json``. The manual renders the newest
run of each table from these files (``app/manual/reference.py``), so no figure there is typed
by hand.

    table = Table("Algorithm 1", ["case", "ms"], rows, align=["left", "right"])
    print(table.markdown())
    record("bench/heatmap.py", [table], "PYTHONPATH=. .venv/bin/python bench/heatmap.py")

A script that prints its tables as Markdown records them by running under ``recorded``:

    if __name__ == "__main__":
        with recorded(__file__):
            main()
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import json
import os
import platform
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "benchmarks"


@dataclass
class Table:
    """One printed table: its title (the first column's header names what is measured), the
    columns and the rows as the cells read (units in the header or the cell)."""

    title: str
    columns: list[str]
    rows: list[list[str]]
    align: list[str] = field(default_factory=list)  # "left" or "right" per column

    def markdown(self) -> str:
        align = self.align or ["left"] + ["right"] * (len(self.columns) - 1)
        rule = "|" + "|".join("---:" if a == "right" else "---" for a in align) + "|"
        lines = ["| " + " | ".join(self.columns) + " |", rule]
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        return "\n".join(lines)


def commit() -> str | None:
    """The checkout's commit (with ``+changes`` when the tree differs from it), or None."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO,
            capture_output=True,
            text=True,
        ).stdout.strip()
    except OSError:
        return None
    return f"{head}+changes" if head and dirty else head or None


def machine() -> str:
    """The machine in words: cores, CPU model, GPU when torch sees one."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    words = f"{os.cpu_count()} CPU cores, {model}"
    try:
        import torch

        if torch.cuda.is_available():
            words += f", {torch.cuda.get_device_name(0)}"
    except ImportError:
        pass
    return words


def record(script: str, tables: Sequence[Table], command: str | None = None) -> Path:
    """Add this run's tables to ``docs/benchmarks/<script stem>.json``; returns the file."""
    path = RESULTS / f"{Path(script).stem}.json"
    data: dict[str, Any] = (
        json.loads(path.read_text()) if path.exists() else {"script": script, "runs": []}
    )
    data["runs"].append(
        {
            "date": dt.date.today().isoformat(),
            "commit": commit(),
            "machine": machine(),
            "command": command or f"PYTHONPATH=. .venv/bin/python {script}",
            "tables": [asdict(table) for table in tables],
        }
    )
    RESULTS.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n")
    return path


RULE = re.compile(r"^\s*\|[\s:|-]+\|\s*$")


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def markdown_tables(text: str) -> list[Table]:
    """The Markdown tables in a script's output (a header row, its rule, the rows)."""
    lines, tables, i = text.splitlines(), [], 0
    while i < len(lines) - 1:
        if lines[i].lstrip().startswith("|") and RULE.match(lines[i + 1]):
            columns = _cells(lines[i])
            align = ["right" if c.endswith(":") else "left" for c in _cells(lines[i + 1])]
            rows, i = [], i + 2
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            tables.append(Table(columns[0], columns, rows, align))
        else:
            i += 1
    return tables


class _Tee(io.TextIOBase):
    def __init__(self, out: Any) -> None:
        self.out, self.seen = out, io.StringIO()

    def write(self, text: str) -> int:
        self.seen.write(text)
        return int(self.out.write(text))

    def flush(self) -> None:
        self.out.flush()


@contextlib.contextmanager
def recorded(script_file: str) -> Iterator[None]:
    """Run a bench's ``main`` under this: what it prints still prints, and the Markdown tables
    among it are recorded (``record``) when it ends without an error."""
    script = f"bench/{Path(script_file).name}"
    tee = _Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield
    tables = markdown_tables(tee.seen.getvalue())
    if tables:
        command = shlex.join(["PYTHONPATH=.", ".venv/bin/python", script, *sys.argv[1:]])
        print(f"{len(tables)} tables written to {record(script, tables, command)}")
