"""A stopped server leaves nothing of its home open: Huey's per-lane connections to the SQLite
queue file (and its journal) are closed with the app, as is each lane's Redis pool."""

from __future__ import annotations

import os
from pathlib import Path

from fastapi.testclient import TestClient

from app.core.db import create_db_engine
from app.core.schema import migrate
from app.main import create_app
from tests.helpers import make_settings


def _migrated(tmp_path: Path, **overrides: str):  # type: ignore[no-untyped-def]
    settings = make_settings(tmp_path / "home", **overrides)
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    engine.dispose()
    return settings


def _open_under(folder: Path) -> list[str]:
    found = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(str(folder)):
            found.append(target)
    return found


def test_a_stopped_server_leaves_no_file_of_its_home_open(tmp_path: Path) -> None:
    settings = _migrated(tmp_path)
    for _ in range(2):  # a lifespan entered again opens the queue again, and closes it again
        with TestClient(create_app(settings, embedded_worker=True)) as client:
            assert client.get("/api/v1/health").json()["queue"]["status"] == "ok"
            assert any("queue.sqlite3" in path for path in _open_under(tmp_path))
        assert _open_under(tmp_path) == []


def test_a_stopped_server_releases_its_redis_connections(tmp_path: Path, redis_url: str) -> None:
    settings = _migrated(tmp_path, queue_url=redis_url)
    app = create_app(settings, embedded_worker=True)
    with TestClient(app) as client:
        assert client.get("/api/v1/health").json()["queue"]["status"] == "ok"
        pools = [huey.storage.pool for huey in app.state.queue._hueys.values()]
    connections = [
        c for pool in pools for c in [*pool._available_connections, *pool._in_use_connections]
    ]
    assert connections and all(c._sock is None for c in connections)
