"""Helpers for tests: settings, authentication headers, polling."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from app.core.config import Settings

POSTGRES_URL = os.environ.get(
    "WELDPOOL_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
REDIS_URL = os.environ.get("WELDPOOL_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@contextmanager
def postgres_schema() -> Iterator[str]:
    """A URL whose connections live in a fresh schema of the real PostgreSQL, dropped after;
    fails (not skips) where PostgreSQL is unreachable."""
    import pytest
    import sqlalchemy as sa

    schema = f"wp_test_{uuid.uuid4().hex[:12]}"
    admin = sa.create_engine(POSTGRES_URL)
    try:
        with admin.begin() as connection:
            connection.execute(sa.text(f'CREATE SCHEMA "{schema}"'))
    except sa.exc.OperationalError as exc:
        pytest.fail(
            f"PostgreSQL at {POSTGRES_URL} is unreachable ({exc.orig}); start it or set "
            "WELDPOOL_TEST_POSTGRES_URL. The suite must run against a real PostgreSQL.",
            pytrace=False,
        )
    url = sa.engine.make_url(POSTGRES_URL).update_query_dict({"options": f"-csearch_path={schema}"})
    try:
        yield url.render_as_string(hide_password=False)
    finally:
        with admin.begin() as connection:
            connection.execute(sa.text(f'DROP SCHEMA "{schema}" CASCADE'))
        admin.dispose()


def real_label_masks() -> list[Path]:
    """The 9 hand-drawn WAAM pool masks (../shared/data/waam/labels, sorted). A checkout without
    ../shared (CI's clean clone) skips the test; the same code runs there on synthetic shapes
    with known answers, in the tests beside it."""
    import pytest

    files = sorted((SHARED_DATA / "waam" / "labels").glob("*.png"))
    if not files:
        pytest.skip("../shared/data/waam/labels is absent (a fresh checkout has no ../shared)")
    return files


def run_cli(
    *args: str | Path, env: dict[str, str] | None = None, stdin: str = "", timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """``weldpool ARGS`` in a child process (offline: never the hub), with ``env`` added."""
    environment = {**os.environ, "HF_HUB_OFFLINE": "1", **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "app", *map(str, args)],
        input=stdin,
        env=environment,
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def fresh_python(
    script: str, *args: str, env: dict[str, str] | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    """``python -c SCRIPT ARGS`` in a fresh process at the repository's root (what a process
    imports at start is only seen there), with ``env`` as its whole environment if given."""
    return subprocess.run(
        [sys.executable, "-c", script, *args],
        env=env,
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def mask_b64(mask: Any) -> str:
    """A mask as the API carries it: a 0/255 PNG, base64."""
    import base64

    from weldpool_core.io import encode_mask_png

    return base64.b64encode(encode_mask_png(mask)).decode()


def mask_from_b64(text: str) -> Any:
    """A mask the API carried (``mask_png``: a 0/255 PNG, base64) as a boolean array."""
    import base64

    from weldpool_core.io import decode_mask_png

    return decode_mask_png(base64.b64decode(text))


def corrected_label(mask: Any, base_revision: int = 0) -> dict[str, Any]:
    """The body of ``PUT /frames/{id}/label`` that saves ``mask`` as a correction."""
    return {"status": "corrected", "base_revision": base_revision, "mask_png": mask_b64(mask)}


def make_settings(home: Path, **overrides: Any) -> Settings:
    """Settings for a test: its own home and queue name, fast heartbeats, no .env file."""
    values: dict[str, Any] = {
        "home": home,
        "queue_name": f"wp-test-{uuid.uuid4().hex[:8]}",
        "job_heartbeat_s": 0.2,
        "job_stale_after_s": 30.0,
    }
    values.update(overrides)
    return Settings(_env_file=None, **values)  # type: ignore[call-arg]


def age_stored_files(home: Path, seconds: float) -> None:
    """Make every stored file look claimed ``seconds`` ago (time passing, for the collector)."""
    then = time.time_ns() - int(seconds * 1e9)
    for area in ("frames", "videos", "artefacts"):
        for path in (home / area).rglob("*") if (home / area).is_dir() else ():
            if path.is_file():
                os.utime(path, ns=(then, then))


def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def wait_for(predicate: Callable[[], Any], timeout: float = 20.0, interval: float = 0.05) -> Any:
    """Poll until ``predicate`` returns something truthy; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"condition not met within {timeout} s")


def wait_for_job(client: TestClient, job_id: int, token: str, timeout: float = 20.0) -> dict:
    """Poll a job until it has finished; returns its JSON."""

    def finished() -> dict | None:
        body = client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()
        return body if body["status"] in ("succeeded", "failed", "cancelled") else None

    return wait_for(finished, timeout)


def image_bytes(
    width: int = 64,
    height: int = 48,
    *,
    channels: int = 1,
    bit_depth: int = 8,
    fmt: str = ".png",
    seed: int = 0,
) -> bytes:
    """An encoded test image with random content (distinct per seed)."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    dtype, top = (np.uint16, 65535) if bit_depth == 16 else (np.uint8, 255)
    shape = (height, width) if channels == 1 else (height, width, channels)
    pixels = rng.integers(0, top, size=shape, endpoint=True).astype(dtype)
    ok, buffer = cv2.imencode(fmt, pixels)
    assert ok
    return buffer.tobytes()


def write_video(
    path: Path, count: int, fps: float = 20.0, size: tuple[int, int] = (96, 64)
) -> Path:
    """An MJPEG AVI of synthetic weld frames; frame i's top-left pixels hold 6·(i mod 40)."""
    import cv2
    import numpy as np

    from weldpool_core.synth import SynthParams, synth_frame

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    for index in range(count):
        frame = synth_frame(index % 3, SynthParams(width=size[0], height=size[1])).image
        bgr = cv2.cvtColor(np.asarray(frame, np.uint8), cv2.COLOR_RGB2BGR)
        bgr[:8, :8] = 6 * (index % 40)
        writer.write(bgr)
    writer.release()
    return path


@contextmanager
def hanging_server() -> Iterator[str]:
    """A TCP server on 127.0.0.1 that accepts every connection and never answers (a store that
    hangs); yields its http:// address. Its connections close when the block ends."""
    listener = socket.create_server(("127.0.0.1", 0), backlog=64)
    listener.settimeout(0.1)
    held: list[socket.socket] = []
    done = threading.Event()

    def accept() -> None:
        while not done.is_set():
            try:
                held.append(listener.accept()[0])
            except TimeoutError:
                continue

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        done.set()
        thread.join(5)
        for connection in [*held, listener]:
            connection.close()


def within(seconds: float, call: Callable[[], Any]) -> Any:
    """``call()``'s result (or the exception it raised, returned), failing when it has not
    finished after ``seconds`` (a bound derived from settings, not a benchmark)."""
    outcome: list[Any] = []

    def run() -> None:
        try:
            outcome.append(call())
        except Exception as exc:
            outcome.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert outcome, f"no answer within {seconds:.0f} s"
    return outcome[0]
