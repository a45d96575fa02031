"""Running the service: serve, worker, migrate."""

from __future__ import annotations

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions
from app.db import create_db_engine, create_session_factory, migrate


@main.command("migrate")
@friendly_errors
def migrate_cmd() -> None:
    """Bring the database schema to the newest revision."""
    settings = load_settings()
    settings.ensure_home()
    migrate(create_db_engine(settings.resolved_database_url))
    click.echo("database is at the newest revision", err=True)


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to bind.")
@click.option("--port", default=8000, show_default=True, type=int)
@click.option("--no-worker", is_flag=True, help="Run no embedded worker (use `weldpool worker`).")
@friendly_errors
def serve(host: str, port: int, no_worker: bool) -> None:
    """Migrate, then serve the API and the browser UI (with an embedded worker)."""
    import uvicorn

    from app.housekeeping import sweep_orphan_files
    from app.main import create_app
    from app.storage import Storage
    from app.users.service import ensure_initial_admin

    settings = load_settings()
    settings.ensure_home()
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    with create_session_factory(engine)() as session:
        password_file = ensure_initial_admin(session, settings.home)
        swept = sweep_orphan_files(session, Storage(settings.home))
    engine.dispose()
    if swept:
        click.echo(
            f"removed {swept} stored files that no row named (an interrupted upload)", err=True
        )
    if password_file:
        click.echo(f"created user 'admin'; its password is in {password_file}", err=True)
    app = create_app(settings, embedded_worker=not no_worker)
    click.echo(f"weldpool serving on http://{host}:{port}", err=True)
    uvicorn.run(app, host=host, port=port, log_config=None, access_log=True)


@main.command()
@click.option("--threads", default=None, type=int, help="Worker threads [WELDPOOL_WORKERS].")
@friendly_errors
def worker(threads: int | None) -> None:
    """A standalone worker on WELDPOOL_QUEUE_URL (stops on Ctrl-C or SIGTERM)."""
    from app.queue import JobQueue, run_standalone_worker

    settings = load_settings()
    queue = JobQueue(settings, open_sessions(settings))
    run_standalone_worker(queue, threads or settings.workers)
