"""What the app starts for its life, the end of its lifespan (a graceful stop) ends."""

from __future__ import annotations

import multiprocessing

from fastapi.testclient import TestClient

from app.core.config import Settings
from app.main import create_app


def test_a_graceful_stop_ends_the_label_import_processes(
    settings: Settings, session_factory
) -> None:
    """A large label import starts a process pool (3 processes, ~195 MiB, on a 3-core
    machine); `serve` stopped gracefully left it running."""
    from app.core.processes import process_pool

    with TestClient(create_app(settings)):
        assert process_pool().submit(int, "7").result(timeout=120) == 7  # as an import does
        started = multiprocessing.active_children()
        assert started
    assert [p.pid for p in started if p.is_alive()] == []
