"""The ``weldpool`` command line: the group, and what every command shares (settings, the
database, one-line errors with exit status 2). Commands live beside it, one module per domain.
"""

from __future__ import annotations

import functools
import importlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
import sqlalchemy as sa
from pydantic import ValidationError

from app.core.config import Settings, get_settings
from app.core.db import create_db_engine, create_session_factory, require_current_schema
from app.core.errors import WeldpoolError
from app.core.logs import configure_logging

F = TypeVar("F", bound=Callable[..., Any])


def fail(message: str) -> None:
    click.echo(f"weldpool: {message}", err=True)
    sys.exit(2)


def friendly_errors(func: F) -> F:
    """Turn user-facing errors into one line on stderr and exit status 2."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except WeldpoolError as exc:
            fail(exc.message)
        except sa.exc.OperationalError as exc:
            fail(
                f"The database is unreachable ({str(exc.orig).strip().splitlines()[0]}); "
                "check WELDPOOL_DATABASE_URL."
            )
        except Exception as exc:
            if not type(exc).__module__.startswith(("botocore", "boto3", "s3transfer")):
                raise
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            fail(
                f"The object store did not answer as expected ({first}); check "
                "WELDPOOL_STORAGE_URL, WELDPOOL_S3_ENDPOINT_URL and the AWS_* credentials."
            )

    return wrapper  # type: ignore[return-value]


def load_settings() -> Settings:
    try:
        return get_settings()
    except ValidationError as exc:
        first = exc.errors()[0]
        fail(f"Bad setting WELDPOOL_{str(first['loc'][0]).upper()}: {first['msg']}.")
        raise  # unreachable


def open_sessions(settings: Settings, *, migrated: bool = True) -> Any:
    from app.proposals import policy
    from app.storage import open_storage

    engine = create_db_engine(settings.resolved_database_url)
    if migrated:
        require_current_schema(engine)
    factory = create_session_factory(engine)
    policy.watch(factory, open_storage(settings))
    return factory


COMMANDS = {
    "serve": "service",
    "worker": "service",
    "migrate": "service",
    "storage": "service",
    "doctor": "doctor",
    "import": "frames",
    "import-labels": "frames",
    "export": "review",
    "demo": "review",
    "process-map": "process",
    "teacher": "teacher",
    "weights": "teacher",
    "train": "student",
    "train-sequential": "student",
    "predict": "student",
    "export-student": "student",
    "stream": "stream",
    "opcua-certificate": "stream",
    "heatmap": "evaluation",
    "eval": "evaluation",
    "user": "users",
    "token": "users",
    "tokens": "users",
}
"""Each command's module in ``app.cli``: a command imports only its own module, so ``serve``
does not load what ``eval`` or ``train`` need (a test checks this list against the modules)."""


class LazyGroup(click.Group):
    """The ``weldpool`` group, whose commands' modules are imported when a command is asked for
    (``--help`` lists them all, and so imports them all)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in COMMANDS and cmd_name not in self.commands:
            importlib.import_module(f"app.cli.{COMMANDS[cmd_name]}")  # registers on `main`
        return super().get_command(ctx, cmd_name)


@click.group(cls=LazyGroup)
@click.version_option(package_name="weldpool")
def main() -> None:
    """weldpool: learn the shape of a molten weld pool from camera frames."""
    settings = load_settings()
    configure_logging(settings.log_level, settings.log_format)


IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"}


def named_files(
    arguments: tuple[str, ...],
    suffixes: set[str],
    kind: str,
    stem: Callable[[Path], str] = lambda path: path.stem,
) -> list[Path]:
    """Files named on the command line, folders expanded to those with ``suffixes`` (sorted).

    ``kind`` names them in errors ("image", "PNG mask"); outputs are named by ``stem``, so two
    files with one stem are refused.
    """
    files: list[Path] = []
    for text in arguments:
        path = Path(text)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in suffixes)
            if not found:
                fail(f"The folder {path} holds no {kind} ({', '.join(sorted(suffixes))}).")
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            fail(f"{path} does not exist; give {kind} files or folders of them.")
    stems = [stem(p) for p in files]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        fail(f"Several {kind} files would write outputs named {twice[0]!r}; rename one.")
    return files


def image_files(arguments: tuple[str, ...]) -> list[Path]:
    """Image files named on the command line, folders expanded to their images (sorted)."""
    return named_files(arguments, IMAGE_SUFFIXES, "image")
