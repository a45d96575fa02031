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
