"""The README opens with the two commands a fresh machine needs, and CI runs the second."""

from __future__ import annotations

import re

from tests.helpers import REPO


def _commands() -> list[str]:
    readme = (REPO / "README.md").read_text()
    head = readme.split("---", 1)[0]
    return re.findall(r"```bash\n(.+?)\n```", head, flags=re.S)


def test_readme_opens_with_exactly_two_commands() -> None:
    commands = _commands()
    assert len(commands) == 2
    install_and_serve, install_and_test = commands
    assert "-c constraints.txt" in install_and_serve and install_and_serve.endswith("serve")
    assert "-c constraints.txt" in install_and_test and "pytest" in install_and_test


def test_ci_runs_the_readme_test_command() -> None:
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    assert _commands()[1] in ci


def test_constraints_hold_torch() -> None:
    lines = (REPO / "constraints.txt").read_text().splitlines()
    assert "torch==2.13.0" in lines
    pyproject = (REPO / "pyproject.toml").read_text()
    assert "torchvision" not in pyproject and "timm" not in pyproject


README_MAX_LINES = 200
LINK = re.compile(r"\]\(([^)\s]+)\)")
CODE = re.compile(r"```[a-z]*\n(.+?)```|`([^`\n]+)`", re.S)
COMMAND = re.compile(r"(?:^|[\s/])weldpool ((?:[a-z][a-z0-9-]*)(?: [a-z][a-z0-9-]*)*)")


def test_readme_is_a_front_door() -> None:
    """Short: what weldpool is, the two commands, a tour, where to go next (the manual)."""
    lines = (REPO / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES


def test_every_relative_link_of_the_readme_resolves() -> None:
    readme = (REPO / "README.md").read_text()
    links = [link for link in LINK.findall(readme) if "://" not in link]
    assert links, "the README links into the manual"
    for link in links:
        path = link.split("#", 1)[0]
        assert (REPO / path).exists(), f"README links to {link}, which does not exist"


def test_every_weldpool_command_of_the_readme_exists() -> None:
    """Each `weldpool <command>` the README names is a command of the click CLI."""
    from app.manual.reference import cli_commands

    known = {name.removeprefix("weldpool ") for name in cli_commands()}
    groups = {name.split(" ")[0] for name in known}
    code = " ".join(a + b for a, b in CODE.findall((REPO / "README.md").read_text()))
    named = set(COMMAND.findall(code))
    assert {"demo", "serve"} <= named
    for words in named:
        parts = words.split(" ")
        # Some prefix of the words is a command (the rest are arguments), or a group alone.
        found = any(" ".join(parts[:n]) in known for n in range(1, len(parts) + 1))
        assert found or (parts == [parts[0]] and parts[0] in groups), f"weldpool {words}"


def test_the_readme_links_into_every_part_of_the_manual() -> None:
    """A newcomer reaches each page of the tour from the README in one click."""
    readme = (REPO / "README.md").read_text()
    for page in (
        "docs/getting-started/index.md",
        "docs/getting-started/weights.md",
        "docs/guides/reviewing.md",
        "docs/guides/student.md",
        "docs/guides/labels.md",
        "docs/operations/deploy.md",
        "docs/reference/cli.md",
    ):
        assert f"]({page}" in readme, page
