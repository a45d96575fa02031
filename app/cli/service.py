"""Running the service: serve, worker, migrate."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions
from app.config import Settings
from app.db import create_db_engine, create_session_factory
from app.errors import WeldpoolError


@main.command("migrate")
@friendly_errors
def migrate_cmd() -> None:
    """Bring the database schema to the newest revision."""
    from app.schema import migrate  # the models with it: imported by the commands that need them

    settings = load_settings()
    settings.ensure_home()
    migrate(create_db_engine(settings.resolved_database_url))
    click.echo("database is at the newest revision", err=True)


def prepare_instance(settings: Settings) -> Path | None:
    """Migrate the database and, on a fresh instance, create ``admin`` (serve and demo).

    Returns the file holding the new admin's password, or None when users already existed.
    """
    from app.schema import migrate
    from app.storage import Storage
    from app.users.service import ensure_initial_admin

    settings.ensure_home()
    Storage.of(settings, for_requests=True).check()  # waits a request's bound, not a job's
    engine = create_db_engine(settings.resolved_database_url)
    try:
        migrate(engine)
        with create_session_factory(engine)() as session:
            return ensure_initial_admin(session, settings.home)
    finally:
        engine.dispose()


def _prepare_below_the_imports(settings: Settings) -> Path | None:
    from app.budgets import lower_priority  # imported by serve before the thread starts

    lower_priority(settings.batch_nice)
    return prepare_instance(settings)


def login_hint(password_file: Path | None, host: str = "127.0.0.1", port: int = 8000) -> str:
    """How to log in, in one sentence, for the messages of serve and demo."""
    where = f"http://{host}:{port}"
    if password_file:
        return (
            f"created user 'admin'; log in at {where} as admin with the password in {password_file}"
        )
    return f"log in at {where} with your account (`weldpool user add NAME` adds one)"


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to bind.")
@click.option("--port", default=8000, show_default=True, type=int)
@click.option("--no-worker", is_flag=True, help="Run no embedded worker (use `weldpool worker`).")
@friendly_errors
def serve(host: str, port: int, no_worker: bool) -> None:
    """Migrate, then serve the API and the browser UI (with an embedded worker)."""
    from app.budgets import lower_priority  # noqa: F401 (see below)
    from app.storage import Storage
    from app.users.service import ensure_initial_admin  # noqa: F401 (see below)

    settings = load_settings()
    with ThreadPoolExecutor(1) as pool:
        # The migration check (or a fresh instance's schema and admin) runs beside the imports
        # of the service. What the thread imports is imported above: two threads importing the
        # same modules can see them half-made. The thread runs at a job's priority, so it takes
        # the core the imports leave rather than half of theirs; it ends with the pool.
        prepared = pool.submit(_prepare_below_the_imports, settings)
        import uvicorn

        from app.housekeeping import prune_training_state, sweep_orphan_files
        from app.main import create_app

        password_file = prepared.result()
    engine = create_db_engine(settings.resolved_database_url)
    with create_session_factory(engine)() as session:
        swept = sweep_orphan_files(session, Storage.of(settings))
        freed = prune_training_state(session, settings.home)
    engine.dispose()
    if freed:
        click.echo(
            f"removed {freed / 2**20:.0f} MB of training state that recorded versions no longer "
            "need",
            err=True,
        )
    if swept:
        click.echo(
            f"removed {swept} stored files that no row named (an interrupted upload)", err=True
        )
    if password_file:
        click.echo(login_hint(password_file, host, port), err=True)
    app = create_app(settings, embedded_worker=not no_worker)
    click.echo(f"weldpool serving on http://{host}:{port}", err=True)
    # X-Forwarded-For and -Proto only from WELDPOOL_TRUSTED_PROXIES (uvicorn's default trusts
    # 127.0.0.1: any local client could then pick the address the login lockout counts).
    proxies = settings.trusted_proxy_list
    uvicorn.run(
        app,
        host=host,
        port=port,
        log_config=None,
        access_log=True,
        proxy_headers=bool(proxies),
        forwarded_allow_ips=proxies,
    )


@main.command()
@click.option("--threads", default=None, type=int, help="Worker threads [WELDPOOL_WORKERS].")
@friendly_errors
def worker(threads: int | None) -> None:
    """A standalone worker on WELDPOOL_QUEUE_URL (stops on Ctrl-C or SIGTERM)."""
    from app.queue import JobQueue, run_standalone_worker
    from app.storage import Storage

    settings = load_settings()
    settings.ensure_home()
    Storage.of(settings, for_requests=True).check()  # waits a request's bound, not a job's
    queue = JobQueue(settings, open_sessions(settings))
    run_standalone_worker(queue, threads or settings.workers)


@main.group("storage")
def storage_group() -> None:
    """The object store (WELDPOOL_STORAGE_URL)."""


@storage_group.command("push")
@friendly_errors
def storage_push() -> None:
    """Upload what WELDPOOL_HOME holds (frames, videos, masks, models, exports) to the object
    store, so an instance that kept its files in home can move to it."""
    from app.storage import ObjectStorage, Storage

    settings = load_settings()
    storage = Storage.of(settings)
    if not isinstance(storage, ObjectStorage):
        raise WeldpoolError("WELDPOOL_STORAGE_URL is not set: there is no store to push to.")
    click.echo(f"uploading {settings.home}'s files to {storage.remote}", err=True)
    uploaded, present = storage.push()
    click.echo(
        f"{uploaded} files uploaded to {storage.remote}, {present} were there already; "
        f"{settings.home} is now its cache",
        err=True,
    )
