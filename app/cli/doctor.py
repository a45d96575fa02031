"""``weldpool doctor``: the rows whose stored files are lost, and what restores each."""

from __future__ import annotations

import sys

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions


@main.command("doctor")
@friendly_errors
def doctor_cmd() -> None:
    """List the rows whose files the store lost (frames' images, label and proposal masks,
    model versions) and what restores each; exit status 1 when any is lost."""
    from app.storage import open_storage
    from app.system.doctor import lost_files

    settings = load_settings()
    storage = open_storage(settings)
    with open_sessions(settings)() as session:
        lost = lost_files(session, storage)
    where = storage.remote or str(settings.home)
    if not lost:
        click.echo(f"every file the database names is in {where}", err=True)
        return
    for item in lost:
        click.echo(item.line())
    also = (
        "; a machine whose cache still holds one can restore it with `weldpool storage push`"
        if storage.remote
        else ""
    )
    click.echo(f"{len(lost)} files the database names are missing from {where}{also}", err=True)
    sys.exit(1)
