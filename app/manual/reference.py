"""Markdown generated from the code, for the manual's reference pages: one generator for mkdocs
(``hook.py``) and /help (``pages.py``), so the tables cannot drift from what they describe."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from functools import cache
from pathlib import Path
from typing import Any

import click

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
BENCHMARKS = DOCS / "benchmarks"
MARKER = re.compile(r"^<!-- weldpool:(\w+)(?: ([\w./-]+))? -->$", re.M)
METHODS = ("get", "post", "put", "patch", "delete")

Schema = Callable[[], dict[str, Any]]


def _cell(text: object) -> str:
    """Text for one table cell: one line, pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _code(text: object) -> str:
    return f"`{text}`" if "`" not in str(text) else f"`` {text} ``"


@cache  # the code does not change while a process runs
def settings_markdown() -> str:
    """Every field of ``Settings``: its variable, default and description."""
    from pydantic_core import PydanticUndefined

    from app.core.config import Settings

    rows = ["| variable | default | meaning |", "|---|---|---|"]
    for name, field in Settings.model_fields.items():
        default: Any = field.default
        if default is PydanticUndefined and field.default_factory is not None:
            default = field.default_factory()  # type: ignore[call-arg]
        shown = "—" if default is None else _code(_cell(_plain(default)))
        meaning = field.description or ""
        rows.append(f"| `WELDPOOL_{name.upper()}` | {shown} | {_cell(meaning)} |")
    return "\n".join(rows)


def _plain(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, Path):
        return str(value) if value.is_absolute() else f"./{value}"
    if isinstance(value, dict | list | tuple):
        return json.dumps(value)
    return str(value)


def _commands(group: click.Group, ctx: click.Context, path: str) -> Iterator[tuple[str, Any]]:
    for name in group.list_commands(ctx):
        command = group.get_command(ctx, name)
        if command is None or command.hidden:
            continue
        full = f"{path} {name}"
        if isinstance(command, click.Group):
            yield from _commands(command, click.Context(command, info_name=name, parent=ctx), full)
        else:
            yield full, command


def cli_commands() -> dict[str, click.Command]:
    """Every leaf command of ``weldpool``, by its full name (``weldpool weights fetch``)."""
    from app.cli import main

    ctx = click.Context(main, info_name="weldpool")
    return dict(_commands(main, ctx, "weldpool"))


def _option_row(param: click.Parameter, ctx: click.Context) -> str | None:
    if not isinstance(param, click.Option) or param.hidden:
        return None
    names = ", ".join(_code(n) for n in [*param.opts, *param.secondary_opts])
    if not param.is_flag:
        names += f" {_cell(param.make_metavar(ctx))}"
    default = param.get_default(ctx, call=False)
    if param.required:
        shown = "required"
    elif default is None or callable(default) or "UNSET" in repr(default) or default == ():
        shown = "—"
    elif param.is_flag and default is False:
        shown = "off"
    else:
        shown = _code(_cell(_plain(default)))
    return f"| {names} | {shown} | {_cell(param.help or '')} |"


@cache  # importing every command's module takes seconds: once per process
def cli_markdown() -> str:
    """Every command: usage, its help text and its options."""
    parts = []
    for full, command in cli_commands().items():
        ctx = click.Context(command, info_name=full)
        usage = " ".join(command.collect_usage_pieces(ctx))
        parts.append(f"## `{full}`\n")
        parts.append(f"```text\n{full} {usage}\n```\n")
        parts.append(_docstring(command.help or ""))
        rows = [row for p in command.params if (row := _option_row(p, ctx))]
        if rows:
            parts.append("| option | default | meaning |\n|---|---|---|\n" + "\n".join(rows) + "\n")
    return "\n".join(parts)


def _docstring(text: str) -> str:
    """A click help text as Markdown paragraphs (click's ``\\b`` markers dropped)."""
    paragraphs = [" ".join(p.split()) for p in text.replace("\b", "").split("\n\n")]
    return "\n\n".join(p for p in paragraphs if p) + "\n"


def api_markdown(schema: dict[str, Any]) -> str:
    """Every operation of the OpenAPI schema, grouped by tag: method, path, summary, description."""
    by_tag: dict[str, list[str]] = {}
    for path, item in schema.get("paths", {}).items():
        for method in METHODS:
            operation = item.get(method)
            if operation is None:
                continue
            tag = (operation.get("tags") or ["other"])[0]
            summary = operation.get("summary", "")
            description = _cell(operation.get("description", ""))
            query = [q["name"] for q in operation.get("parameters", []) if q.get("in") == "query"]
            if query:
                description += " Query: " + ", ".join(f"`{name}`" for name in query) + "."
            by_tag.setdefault(tag, []).append(
                f"| `{method.upper()}` | `{path}` | **{_cell(summary)}** {description} |"
            )
    parts = []
    for tag in sorted(by_tag):
        parts.append(f"## {tag.capitalize()}\n\n| method | path | does |\n|---|---|---|")
        parts.append("\n".join(by_tag[tag]) + "\n")
    return "\n".join(parts)


def benchmark_files() -> dict[str, dict[str, Any]]:
    """``docs/benchmarks/*.json`` by name."""
    return {p.stem: json.loads(p.read_text()) for p in sorted(BENCHMARKS.glob("*.json"))}


def _latest_tables(data: dict[str, Any]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Each table (by its title, the first column's header) from the newest run that has it,
    with that run; a run's tables of one title are shown together."""
    latest: dict[str, list[tuple[dict[str, Any], dict[str, Any]]]] = {}
    for run in sorted(data["runs"], key=lambda r: r["date"]):
        titles = dict.fromkeys(table["title"] for table in run["tables"])
        for title in titles:
            latest[title] = [(run, table) for table in run["tables"] if table["title"] == title]
    return [pair for pairs in latest.values() for pair in pairs]


def _table(table: dict[str, Any]) -> str:
    align = table.get("align") or ["left"] * len(table["columns"])
    rule = "|" + "|".join("---:" if a == "right" else "---" for a in align) + "|"
    lines = ["| " + " | ".join(table["columns"]) + " |", rule]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in table["rows"]]
    return "\n".join(lines)


def _measured(run: dict[str, Any]) -> str:
    commit = f", commit `{run['commit']}`" if run.get("commit") else ""
    return f"*Measured {run['date']}{commit} on {run['machine']}; `{run['command']}`.*"


def benchmark_markdown(name: str) -> str:
    """The latest tables of one benchmark file, each with when and where it was measured."""
    data = benchmark_files().get(name)
    if data is None:
        raise KeyError(f"docs/benchmarks/{name}.json does not exist.")
    return "\n\n".join(
        f"{_table(table)}\n\n{_measured(run)}" for run, table in _latest_tables(data)
    )


def _script_summary(script: str) -> str:
    path = REPO / script
    if not path.is_file():
        return ""
    match = re.match(r'\s*(?:#[^\n]*\n|\s)*"""(.*?)(?:\n\n|""")', path.read_text(), re.S)
    return " ".join(match.group(1).split()) if match else ""


def benchmarks_markdown() -> str:
    """Every benchmark file: a section per script with its summary and latest tables."""
    parts = []
    for name, data in benchmark_files().items():
        summary = _script_summary(data["script"])
        parts.append(f"## `{data['script']}`\n\n{summary}\n\n{benchmark_markdown(name)}\n")
    return "\n".join(parts)


def expand(markdown: str, schema: Schema) -> str:
    """The page with each ``<!-- weldpool:… -->`` marker replaced by what it stands for;
    ``schema`` gives the OpenAPI schema (asked for only when the page needs it)."""

    def replace(match: re.Match[str]) -> str:
        kind, argument = match.group(1), match.group(2)
        if kind == "settings":
            return settings_markdown()
        if kind == "cli":
            return cli_markdown()
        if kind == "api":
            return api_markdown(schema())
        if kind == "benchmarks":
            return benchmarks_markdown()
        if kind == "benchmark" and argument:
            return benchmark_markdown(argument)
        if kind == "include" and argument:
            return (REPO / argument).read_text()
        raise ValueError(f"Unknown manual marker {match.group(0)}.")

    return MARKER.sub(replace, markdown)
