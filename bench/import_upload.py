"""Benchmark a label import's upload: ``POST /api/v1/labels/import`` of one large zip, from the
request's first byte to its 202 (the multipart body read and the zip put under ``imports/``
for its job; the job itself is not run).

Run: ``PYTHONPATH=. .venv/bin/python bench/import_upload.py [--mb 256] [--runs 5]``

The zip is stored (not compressed) random bytes in one member: what the route does with it
does not depend on its content. The service runs in process (``TestClient``, SQLite, no
worker); the body is sent in 1 MiB chunks (fewer rounds through the test client). Median of
``--runs``, with the process's CPU time beside the wall time.
"""

from __future__ import annotations

import argparse
import io
import resource
import statistics
import tempfile
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient
from results import recorded

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role, User
from app.core.schema import migrate
from app.core.security import hash_password, issue_token
from app.main import create_app

CHUNK = 1 << 20


def archive(megabytes: int) -> bytes:
    buffer = io.BytesIO()
    data = np.random.default_rng(0).integers(0, 256, megabytes << 20, dtype=np.uint8).tobytes()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as zipped:
        zipped.writestr("masks/big.bin", data)
    return buffer.getvalue()


def body(data: bytes) -> tuple[bytes, bytes, bytes]:
    head = (
        b'--b\r\nContent-Disposition: form-data; name="format"\r\n\r\nmasks\r\n'
        b'--b\r\nContent-Disposition: form-data; name="file"; filename="set.zip"\r\n'
        b"Content-Type: application/zip\r\n\r\n"
    )
    return head, data, b"\r\n--b--\r\n"


def chunks(parts: tuple[bytes, bytes, bytes]) -> Iterator[bytes]:
    head, data, tail = parts
    yield head
    view = memoryview(data)
    for start in range(0, len(data), CHUNK):
        yield bytes(view[start : start + CHUNK])
    yield tail


def token_for(settings: Settings) -> str:
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    with create_session_factory(engine)() as session:
        user = User(username="bench", password_hash=hash_password("bench-bench"), role=Role.admin)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user, "bench")
        session.commit()
    engine.dispose()
    return token


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mb", type=int, default=256)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    parts = body(archive(args.mb))
    walls, cpus = [], []
    with tempfile.TemporaryDirectory() as home:
        settings = Settings(_env_file=None, home=Path(home))  # type: ignore[call-arg]
        token = token_for(settings)
        headers = {
            "Authorization": f"Bearer {token}",
            "Content-Type": "multipart/form-data; boundary=b",
        }
        with TestClient(create_app(settings, embedded_worker=False)) as client:
            for _ in range(args.runs):
                before = resource.getrusage(resource.RUSAGE_SELF)
                start = time.perf_counter()
                response = client.post(
                    "/api/v1/labels/import", content=chunks(parts), headers=headers
                )
                walls.append(time.perf_counter() - start)
                after = resource.getrusage(resource.RUSAGE_SELF)
                cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
                assert response.status_code == 202, response.text
    wall, cpu = statistics.median(walls), statistics.median(cpus)
    print(f"one {args.mb} MB zip, median of {args.runs}\n")
    print("| upload | wall ms | CPU ms | MB/s |")
    print("|---|---:|---:|---:|")
    print(f"| labels/import | {wall * 1000:.0f} | {cpu * 1000:.0f} | {args.mb / wall:.0f} |")


if __name__ == "__main__":
    with recorded(__file__):
        main()
