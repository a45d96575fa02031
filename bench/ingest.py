"""Frames per second through POST /api/v1/frames, median of several runs.

Uploads the 62 real WAAM frames of ../shared/data/waam/frames (when present) and a generated
batch of 1280×800 PNG frames, in batches of N files per request, from one or two concurrent
clients; one file per request is the naive way the ratio compares with. Then what the same
real frames cost in process on every core: hashed and checked as ingest does (its CPU floor),
and hashed and decoded to every pixel (the way before ``check_image``).

    .venv/bin/python bench/ingest.py                 # starts a throw-away server (SQLite)
    .venv/bin/python bench/ingest.py --url http://127.0.0.1:8000 --token wp_…
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import time
import zlib
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import cv2
import httpx
import numpy as np
from common import SHARED_DATA, local_server

from weldpool_core.io import check_image, read_image

REAL_FRAMES = SHARED_DATA / "waam" / "frames"


def generated_frames(count: int, seed: int = 0) -> list[tuple[str, bytes]]:
    """Distinct 1280×800 gray PNGs that look roughly like a weld scene (smooth, not noise)."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 255, (800, 1280), dtype=np.uint8), (0, 0), 25)
    base = cv2.normalize(base, None, 40, 200, cv2.NORM_MINMAX)
    frames = []
    for index in range(count):
        frame = base.copy()
        centre = (640 + int(80 * np.sin(index / 20)), 420 + int(40 * np.cos(index / 15)))
        cv2.ellipse(frame, centre, (260, 150), index % 180, 0, 360, 25, -1)
        cv2.circle(frame, (centre[0] + 200, centre[1] - 120), 60, 250, -1)
        frame = cv2.add(frame, rng.integers(0, 6, frame.shape, dtype=np.uint8))
        _, data = cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, 3])
        frames.append((f"gen_{seed}_{index:05d}.png", data.tobytes()))
    return frames


def upload_run(
    url: str, token: str, frames: list[tuple[str, bytes]], batch: int, clients: int, run: str
) -> float:
    """Upload every frame into a new sequence; returns frames per second.

    The client and its connections are made before the clock starts, as an uploader that sends
    many batches keeps them (making an httpx client loads its TLS certificates: ~35 ms here).
    """
    headers = {"Authorization": f"Bearer {token}"}
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    with httpx.Client(base_url=url, headers=headers, timeout=300, limits=limits) as http:
        sequence = http.post("/api/v1/sequences", json={"name": run}).json()["id"]
        batches = [frames[i : i + batch] for i in range(0, len(frames), batch)]

        def send(chunk: list[tuple[str, bytes]]) -> int:
            response = http.post(
                "/api/v1/frames",
                data={"sequence_id": str(sequence)},
                files=[("files", (n, d, "image/png")) for n, d in chunk],
            )
            response.raise_for_status()
            return len(response.json()["stored"])

        with ThreadPoolExecutor(clients) as pool:
            list(pool.map(lambda _: http.get("/api/v1/health"), range(clients)))  # connect
            start = time.perf_counter()
            stored = sum(pool.map(send, batches))
            elapsed = time.perf_counter() - start
    assert stored == len(frames), f"stored {stored} of {len(frames)}"
    return len(frames) / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url")
    parser.add_argument("--token")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--generated", type=int, default=1000)
    parser.add_argument("--batch", type=int, default=50)
    args = parser.parse_args()

    sets: list[tuple[str, list[tuple[str, bytes]]]] = []
    if REAL_FRAMES.is_dir():
        sets.append(
            ("waam real", [(p.name, p.read_bytes()) for p in sorted(REAL_FRAMES.glob("*.png"))])
        )
    else:
        print(f"({REAL_FRAMES} is absent: real frames skipped)")
    sets.append(("generated", generated_frames(args.generated)))

    with local_server() if not args.url else _given(args.url, args.token) as (url, token):
        rows = []
        counter = 0
        for name, frames in sets:
            everything, half = len(frames), -(-len(frames) // 2)
            configs = (  # the real set: one file a request, all in one, half each on two clients
                [(1, 1), (everything, 1), (half, 2)]
                if name == "waam real"
                else [(args.batch, 1), (args.batch, 2)]
            )
            for batch, clients in configs:
                rates = []
                for _ in range(args.runs):
                    counter += 1
                    # Distinct content per run, so that no run is answered by deduplication.
                    run_frames = frames if counter == 1 else _salted(frames, counter)
                    rates.append(
                        upload_run(
                            url, token, run_frames, batch, clients, f"bench-{time.time_ns()}"
                        )
                    )
                rows.append((name, len(frames), batch, clients, statistics.median(rates)))
        naive = next((r[4] for r in rows if r[2] == 1), None)
        size = sum(len(d) for _, d in sets[0][1]) / len(sets[0][1]) / 1024
        print(
            f"\nPOST /api/v1/frames, median of {args.runs} runs (mean file {size:.0f} KiB in "
            f"'{sets[0][0]}')"
        )
        print(
            f"{'set':<11} {'frames':>6} {'files/request':>13} {'clients':>7} "
            f"{'frames/s':>9} {'vs 1 file/request':>18}"
        )
        for name, count, batch, clients, rate in rows:
            ratio = f"{rate / naive:.1f}x" if naive else "-"
            print(f"{name:<11} {count:>6} {batch:>13} {clients:>7} {rate:>9.1f} {ratio:>18}")
        _print_floors(sets[0][0], [data for _, data in sets[0][1]], args.runs)


def _print_floors(name: str, frames: list[bytes], runs: int) -> None:
    """What checking the frames costs alone, on every core, against decoding them."""
    threads = os.cpu_count() or 1
    print(f"\nthe same '{name}' frames in process, {threads} threads, median of {runs} runs")
    with ThreadPoolExecutor(threads) as pool:
        for label, work in (
            ("sha256 + check_image (what ingest does)", _check),
            ("sha256 + read_image (every pixel decoded)", _decode),
        ):
            times = []
            for _ in range(runs):
                start = time.perf_counter()
                list(pool.map(work, frames))
                times.append(time.perf_counter() - start)
            seconds = statistics.median(times)
            print(f"{label:<42} {seconds * 1000:7.1f} ms {len(frames) / seconds:8.1f} frames/s")


def _check(data: bytes) -> None:
    hashlib.sha256(data).digest()
    check_image(data)


def _decode(data: bytes) -> None:
    hashlib.sha256(data).digest()
    read_image(data)


def _salted(frames: list[tuple[str, bytes]], salt: int) -> list[tuple[str, bytes]]:
    """The same images with a private PNG chunk appended, so their hashes differ."""
    body = b"weLd" + salt.to_bytes(4, "big")
    chunk = b"\x00\x00\x00\x04" + body + zlib.crc32(body).to_bytes(4, "big")
    salted = []
    for name, data in frames:
        end = data.rfind(b"IEND") - 4
        salted.append((name, data[:end] + chunk + data[end:]))
    return salted


@contextmanager
def _given(url: str, token: str | None) -> Iterator[tuple[str, str]]:
    if not token:
        raise SystemExit("--token is needed with --url")
    yield url, token


if __name__ == "__main__":
    main()
