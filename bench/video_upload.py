"""Benchmark a video upload: ``POST /api/v1/videos`` of one large video, from the request's first
byte to its 202 (the multipart body read, the video stored and probed, its row and job made;
the job itself is not run), written once against written twice.

Run: ``PYTHONPATH=. .venv/bin/python bench/video_upload.py [--mb 128] [--pairs 3]``

- **written once** (the route as it is): the part is spooled into the store's scratch folder,
  hashed on the way, and renamed into its content path (``Storage.put_file``).
- **copied** (the route before): the part is spooled to the system's temporary folder
  (``one_spooled_file`` without ``spool_dir``), then copied and hashed into the store
  (``put_stream``).

The video is an MJPEG AVI of noise frames (``--mb`` or a little more), so that the probe opens
it as it would a camera's. The two ways run in interleaved pairs (the first of each pair
alternates), each upload a fresh file: the stored copy is removed after each, so the same
content is never claimed instead of written. The service runs in process (``TestClient``,
SQLite, no worker), the body is sent in 1 MiB chunks; the process's CPU time is beside the wall
time (the hash, the copy and the test client's own work).
"""

from __future__ import annotations

import argparse
import contextlib
import resource
import statistics
import tempfile
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from fastapi.testclient import TestClient
from import_upload import chunks, token_for
from results import Table, recorded

from app.core.config import Settings
from app.frames import routes
from app.main import create_app
from app.storage.writes import content_path

WAYS = ("copied", "written once")


def noise_video(path: Path, megabytes: int) -> int:
    """An MJPEG AVI of 640×480 noise frames of at least ``megabytes``; its size in bytes."""
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (480, 640, 3), dtype=np.uint8) for _ in range(8)]

    def write(count: int) -> int:
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (640, 480))
        for index in range(count):
            writer.write(frames[index % len(frames)])
        writer.release()
        return path.stat().st_size

    per_frame = write(len(frames)) / len(frames)  # the writer's own JPEG quality
    return write(int((megabytes << 20) / per_frame) + 1)


@contextlib.asynccontextmanager
async def spooled_elsewhere(
    request: Any, what: str, max_fields: int = 16, spool_dir: Path | None = None, **_: Any
) -> AsyncIterator[Any]:
    """The route before: its part spooled to the system's temporary folder, then copied."""
    async with ONE_SPOOLED_FILE(request, what, max_fields) as form:
        yield form


ONE_SPOOLED_FILE = routes.one_spooled_file


@contextlib.contextmanager
def way(name: str) -> Iterator[None]:
    """The route as it is (``written once``) or as it was (``copied``), for one upload."""
    if name == "copied":
        routes.one_spooled_file = spooled_elsewhere  # type: ignore[assignment]
    try:
        yield
    finally:
        routes.one_spooled_file = ONE_SPOOLED_FILE


def body(video: bytes) -> tuple[bytes, bytes, bytes]:
    head = (
        b'--b\r\nContent-Disposition: form-data; name="file"; filename="run.avi"\r\n'
        b"Content-Type: video/x-msvideo\r\n\r\n"
    )
    return head, video, b"\r\n--b--\r\n"


def upload(
    client: TestClient, parts: tuple[bytes, bytes, bytes], headers: dict[str, str], home: Path
) -> int:
    """Upload a video, then remove its stored file (the next upload writes anew); its size."""
    response = client.post("/api/v1/videos", content=chunks(parts), headers=headers)
    assert response.status_code == 202, response.text
    video = response.json()["video"]
    (home / content_path("videos", video["sha256"], ".avi")).unlink()
    return int(video["size_bytes"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mb", type=int, default=128)
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args()
    walls: dict[str, list[float]] = {w: [] for w in WAYS}
    cpus: dict[str, list[float]] = {w: [] for w in WAYS}
    with tempfile.TemporaryDirectory() as folder:
        source, small = Path(folder) / "run.avi", Path(folder) / "warm.avi"
        size = noise_video(source, args.mb)
        noise_video(small, 1)
        parts, warm = body(source.read_bytes()), body(small.read_bytes())
        settings = Settings(_env_file=None, home=Path(folder) / "home")  # type: ignore[call-arg]
        token = token_for(settings)
        headers = {
            "Authorization": f"Bearer {token}",
            "Content-Type": "multipart/form-data; boundary=b",
        }
        with TestClient(create_app(settings, embedded_worker=False)) as client:
            for name in WAYS:  # each way's first request, not measured
                with way(name):
                    upload(client, warm, headers, settings.home)
            for pair in range(args.pairs):
                for name in WAYS if pair % 2 == 0 else WAYS[::-1]:
                    with way(name):
                        before = resource.getrusage(resource.RUSAGE_SELF)
                        start = time.perf_counter()
                        stored = upload(client, parts, headers, settings.home)
                        walls[name].append(time.perf_counter() - start)
                        after = resource.getrusage(resource.RUSAGE_SELF)
                    cpus[name].append(
                        after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
                    )
                    assert stored == size
    megabytes = size / (1 << 20)
    rows = []
    for name in WAYS:
        wall, cpu = statistics.median(walls[name]), statistics.median(cpus[name])
        rows.append(
            [
                name,
                " / ".join(f"{w * 1000:.0f}" for w in walls[name]),
                f"{wall * 1000:.0f}",
                f"{cpu * 1000:.0f}",
                f"{megabytes / wall:.0f}",
            ]
        )
    print(f"one {megabytes:.0f} MB MJPEG AVI, {args.pairs} interleaved pairs\n")
    table = Table(
        "video upload",
        ["video upload", "wall ms per run", "wall ms (median)", "CPU ms (median)", "MB/s"],
        rows,
    )
    print(table.markdown())


if __name__ == "__main__":
    with recorded(__file__):
        main()
