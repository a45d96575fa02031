"""What the benchmark scripts share: a throw-away `weldpool serve` on a temporary home."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("WELDPOOL_SHARED_DATA") or REPO.parent / "shared" / "data")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextmanager
def local_server(
    env: dict[str, str] | None = None,
    worker: bool = True,
    setup: Sequence[Sequence[str]] = (),
) -> Iterator[tuple[str, str]]:
    """`weldpool serve` on a temporary home (SQLite); yields (url, the first admin's token).
    ``setup``: weldpool commands run on that home first (e.g. ``[("demo",)]``)."""
    with tempfile.TemporaryDirectory() as home:
        environment = dict(os.environ, WELDPOOL_HOME=home, WELDPOOL_LOG_LEVEL="WARNING")
        environment.update(env or {})
        weldpool = [sys.executable, "-m", "app"]
        for command in setup:
            subprocess.run(
                [*weldpool, *command], env=environment, cwd=REPO, check=True, capture_output=True
            )
        port = free_port()
        command = [*weldpool, "serve", "--port", str(port)] + ([] if worker else ["--no-worker"])
        server = subprocess.Popen(command, env=environment, cwd=REPO, stderr=subprocess.DEVNULL)
        url = f"http://127.0.0.1:{port}"
        try:
            for _ in range(600):
                try:
                    httpx.get(f"{url}/api/v1/health", timeout=1)
                    break
                except httpx.HTTPError:
                    time.sleep(0.1)
            token = subprocess.run(
                [*weldpool, "token", "admin"],
                env=environment,
                cwd=REPO,
                text=True,
                capture_output=True,
                check=True,
            ).stdout.strip()
            yield url, token
        finally:
            server.terminate()
            server.wait(timeout=60)


def admin_token(database_url: str) -> str:
    """A migrated database at ``database_url`` with an admin ``bench``; its API token."""
    from app.core.db import create_db_engine, create_session_factory
    from app.core.models import Role, User
    from app.core.schema import migrate
    from app.core.security import issue_token

    engine = create_db_engine(database_url)
    migrate(engine)
    try:
        with create_session_factory(engine)() as session:
            user = User(username="bench", password_hash="x", role=Role.admin)
            session.add(user)
            session.flush()
            _, token = issue_token(session, user, "bench")
            session.commit()
    finally:
        engine.dispose()
    return token
