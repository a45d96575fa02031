"""Running the service: serve, worker, migrate."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions
from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.errors import ConfigurationError, WeldpoolError


@main.command("migrate")
@friendly_errors
def migrate_cmd() -> None:
    """Bring the database schema to the newest revision."""
    from app.core.schema import (
        migrate,  # the models with it: imported by the commands that need them
    )

    settings = load_settings()
    settings.ensure_home()
    migrate(create_db_engine(settings.resolved_database_url))
    click.echo("database is at the newest revision", err=True)


def prepare_instance(settings: Settings) -> Path | None:
    """Migrate the database and, on a fresh instance, create ``admin`` (serve and demo).

    Returns the file holding the new admin's password, or None when users already existed.
    """
    from app.core.schema import migrate
    from app.storage import open_storage
    from app.users.service import ensure_initial_admin

    settings.ensure_home()
    open_storage(settings, for_requests=True).check()  # waits a request's bound, not a job's
    engine = create_db_engine(settings.resolved_database_url)
    try:
        migrate(engine)
        with create_session_factory(engine)() as session:
            return ensure_initial_admin(session, settings.home)
    finally:
        engine.dispose()


def _prepare_below_the_imports(settings: Settings) -> Path | None:
    from app.core.budgets import lower_priority  # imported by serve before the thread starts

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
    from app.core.budgets import lower_priority  # noqa: F401 (see below)
    from app.users.service import ensure_initial_admin  # noqa: F401 (see below)

    settings = load_settings()
    with ThreadPoolExecutor(1) as pool:
        # The migration check (or a fresh instance's schema and admin) runs beside the imports
        # of the service. What the thread imports is imported above: two threads importing the
        # same modules can see them half-made. The thread runs at a job's priority, so it takes
        # the core the imports leave rather than half of theirs; it ends with the pool.
        prepared = pool.submit(_prepare_below_the_imports, settings)
        import uvicorn

        from app.main import create_app

        password_file = prepared.result()
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
@click.option(
    "--lanes",
    default="quick,model",
    show_default=True,
    help="The lanes this worker serves: quick (exports, imports, videos, int8), model "
    "(training, the teacher, propagation, embeddings), or both.",
)
@friendly_errors
def worker(threads: int | None, lanes: str) -> None:
    """A standalone worker on WELDPOOL_QUEUE_URL (stops on Ctrl-C or SIGTERM).

    At start it checks what it can run (its file store is the web's, the device, the
    teacher's and SAM2's weights) and
    registers that with its lanes: it passes on the jobs it cannot run to a worker that can,
    and refuses to start when it could run nothing at all."""
    from app.jobs.queue import JobQueue, find_unable, run_standalone_worker
    from app.jobs.registry import LANES, kinds_in
    from app.storage import open_storage

    served = tuple(lane for lane in LANES if lane in {p.strip() for p in lanes.split(",")})
    if not served or len(served) != len({p.strip() for p in lanes.split(",") if p.strip()}):
        raise ConfigurationError(f"--lanes takes quick, model or both, not {lanes!r}.")
    settings = load_settings()
    settings.ensure_home()
    open_storage(settings, for_requests=True).check()  # waits a request's bound, not a job's
    queue = JobQueue(settings, open_sessions(settings))
    unable = find_unable(queue, served, standalone=True)
    if len(unable) == len(kinds_in(served)):
        raise ConfigurationError(
            f"This worker can run no job of its lanes: {next(iter(unable.values()))}"
        )
    for kind, reason in sorted(unable.items()):
        click.echo(f"this worker passes {kind} jobs on: {reason}", err=True)
    run_standalone_worker(queue, threads or settings.workers, served)


@main.group("storage")
def storage_group() -> None:
    """The object store (WELDPOOL_STORAGE_URL)."""


@storage_group.command("push")
@friendly_errors
def storage_push() -> None:
    """Upload what WELDPOOL_HOME holds (frames, videos, masks, models, exports) to the object
    store, so an instance that kept its files in home can move to it."""
    from app.storage import ObjectStorage, open_storage

    settings = load_settings()
    storage = open_storage(settings)
    if not isinstance(storage, ObjectStorage):
        raise WeldpoolError("WELDPOOL_STORAGE_URL is not set: there is no store to push to.")
    click.echo(f"uploading {settings.home}'s files to {storage.remote}", err=True)
    uploaded, present = storage.push()
    click.echo(
        f"{uploaded} files uploaded to {storage.remote}, {present} were there already; "
        f"{settings.home} is now its cache",
        err=True,
    )


@storage_group.command("create-bucket")
@friendly_errors
def storage_create_bucket() -> None:
    """Create the bucket of WELDPOOL_STORAGE_URL in the object store (a new deployment's first
    step; a bucket that exists is left as it is)."""
    from botocore.exceptions import ClientError

    from app.storage import ObjectStorage, open_storage

    settings = load_settings()
    storage = open_storage(settings)
    if not isinstance(storage, ObjectStorage):
        raise WeldpoolError("WELDPOOL_STORAGE_URL is not set: there is no bucket to create.")
    client, bucket = storage.objects.client, storage.objects.name
    try:
        client.head_bucket(Bucket=bucket)
        click.echo(f"the bucket {bucket} exists already", err=True)
        return
    except ClientError as exc:
        if exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode") != 404:
            raise WeldpoolError(
                f"The bucket {bucket} cannot be checked ({exc}); check the AWS_* credentials."
            ) from None
    region = client.meta.region_name
    where = {"CreateBucketConfiguration": {"LocationConstraint": region}}
    client.create_bucket(Bucket=bucket, **({} if region in (None, "us-east-1") else where))
    click.echo(f"created the bucket {bucket} in {storage.remote}", err=True)
