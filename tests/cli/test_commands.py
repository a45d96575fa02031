"""The command group imports a command's module only when that command runs."""

from __future__ import annotations

import importlib
import subprocess
import sys

from app.cli.base import COMMANDS, main


def test_the_command_list_names_each_command_s_own_module() -> None:
    for module in set(COMMANDS.values()):
        importlib.import_module(f"app.cli.{module}")
    registered = {name: command.callback.__module__ for name, command in main.commands.items()}
    assert registered == {name: f"app.cli.{module}" for name, module in COMMANDS.items()}


def test_a_command_imports_only_its_own_module() -> None:
    """`weldpool migrate --help` loads app.cli.service, not the evaluation or training CLIs."""
    probe = (
        "import sys\n"
        "from click.testing import CliRunner\n"
        "from app.cli import main\n"
        "result = CliRunner().invoke(main, ['migrate', '--help'])\n"
        "assert result.exit_code == 0, result.output\n"
        "print(sorted(m for m in sys.modules if m.startswith('app.cli.')))\n"
        "print(sorted(m for m in ('numpy', 'cv2', 'alembic') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out == ["['app.cli.base', 'app.cli.service']", "[]"]
