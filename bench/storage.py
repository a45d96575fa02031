"""Object storage: ingest into an S3-protocol store against home, the S3 clients, and the
object reads of a click from a cold cache.

Starts moto's standalone S3 server on loopback (the one the tests use; MinIO or AWS are
faster), then:

1. ``POST /api/v1/frames`` of the 62 real WAAM frames (a throw-away `weldpool serve`, SQLite, no
   worker) on the home folder and on ``WELDPOOL_STORAGE_URL=s3://…``: frames/s, median of
   ``--runs``, the ratio (goal ≥ 0.7×), and the web server's own CPU per frame. Two placements:
   every process on every core (moto's CPU per PUT then competes with the server's), and the
   store on a core of its own (moto pinned to the last core; the web server and the uploader
   on the others, for home and S3 alike), as a store on another machine would be.
2. The same 62 frames put straight into a bucket from 8 threads, as ingest puts them (a
   conditional PUT carrying its claim), with boto3 and with the store's obstore client: the
   client's share of the time.
3. A click on a frame in a web process whose cache is cold (a fresh home, the frame written by
   another process): the object reads it makes (goal ≤ 1), and the second click's.

    PYTHONPATH=. .venv/bin/python bench/storage.py [--runs 5]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import itertools
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import httpx
from common import SHARED_DATA, admin_token, free_port, local_server
from ingest import _salted, generated_frames, upload_run
from results import Table, recorded

REAL_FRAMES = SHARED_DATA / "waam" / "frames"
os.environ.setdefault("AWS_ACCESS_KEY_ID", "bench")
os.environ.setdefault("AWS_SECRET_ACCESS_KEY", "bench")
os.environ.setdefault("AWS_REGION", "us-east-1")


SERVER_PID = 0


def process_cpu_s(pid: int) -> float:
    """CPU seconds process ``pid`` has used, its threads included (``/proc/<pid>/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def server_cpu_s() -> float:
    """CPU seconds the S3 server process has used."""
    return process_cpu_s(SERVER_PID)


def web_server_pid(url: str) -> int:
    """The `weldpool serve` that ``local_server`` started at ``url``: this process's child."""
    port = url.rsplit(":", 1)[1].encode()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            status = (entry / "status").read_text()
            command = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        parent = next(int(v.split()[1]) for v in status.splitlines() if v.startswith("PPid:"))
        if parent == os.getpid() and b"serve" in command and port in command:
            return int(entry.name)
    raise RuntimeError("the web server is not a child of this process")


@contextmanager
def moto_server(core: int | None = None, keep_alive: bool = False) -> Iterator[str]:
    """moto on loopback: its standalone server (werkzeug: a new connection per request), or
    with ``keep_alive`` its app behind waitress (``moto_waitress.py``); pinned to ``core``
    when given."""
    global SERVER_PID
    port = free_port()
    waitress = [sys.executable, str(Path(__file__).with_name("moto_waitress.py")), str(port)]
    werkzeug = [str(Path(sys.executable).with_name("moto_server")), "-H", "127.0.0.1"]
    command = waitress if keep_alive else [*werkzeug, "-p", str(port)]
    process = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        preexec_fn=None if core is None else lambda: os.sched_setaffinity(0, {core}),
    )
    SERVER_PID = process.pid
    endpoint = f"http://127.0.0.1:{port}"
    try:
        for _ in range(300):
            try:
                httpx.get(endpoint, timeout=1)
                break
            except httpx.HTTPError:
                time.sleep(0.1)
        yield endpoint
    finally:
        process.terminate()
        process.wait(timeout=20)


@contextmanager
def on_cores(cores: set[int] | None) -> Iterator[None]:
    """Run this process (and the processes it starts meanwhile) on ``cores`` only."""
    before = os.sched_getaffinity(0)
    if cores:
        os.sched_setaffinity(0, cores)
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def bucket(endpoint: str) -> str:
    import boto3

    name = f"bench-{time.time_ns()}"
    boto3.client("s3", endpoint_url=endpoint).create_bucket(Bucket=name)
    return name


def machine_cpu_s() -> float:
    """CPU seconds every process on this machine has used (``/proc/stat``: all but idle and
    I/O wait), to put a rate against what the two cores can give."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(values[:8]) - values[3] - values[4]) / os.sysconf("SC_CLK_TCK")


def ingest_rates(
    frames: list[tuple[str, bytes]], stores: dict[str, dict[str, str]], runs: int
) -> dict[tuple[str, int, int], tuple[float, ...]]:
    """(frames/s, machine CPU ms a frame, the web server's CPU ms a frame, the S3 server's CPU
    ms a frame) for (store, files per request, clients): all in one request, half on each of
    two; medians of runs. One `weldpool serve` per store, all up at once, and each run goes
    through every store in turn (which goes first alternates), so that what else the machine
    does weighs on all alike."""
    rates: dict[tuple[str, int, int], list[tuple[float, ...]]] = {}
    configs = ((len(frames), 1), (-(-len(frames) // 2), 2))
    with contextlib.ExitStack() as servers:
        started = {}
        for label, env in stores.items():
            url, token = servers.enter_context(local_server(env, worker=False))
            started[label] = (url, token, web_server_pid(url))
        for run in range(runs):
            order = list(started.items())[:: 1 if run % 2 == 0 else -1]  # each first in turn
            for (label, (url, token, web)), (batch, clients) in itertools.product(order, configs):
                meters = (machine_cpu_s, lambda pid=web: process_cpu_s(pid), server_cpu_s)
                salted = _salted(frames, run * 10 + clients)  # new content each run
                before = [meter() for meter in meters]
                rate = upload_run(url, token, salted, batch, clients, f"b-{time.time_ns()}")
                used = [(m() - b) * 1000 / len(frames) for m, b in zip(meters, before, strict=True)]
                rates.setdefault((label, batch, clients), []).append((rate, *used))
    return {
        config: tuple(statistics.median(v[i] for v in values) for i in range(4))
        for config, values in rates.items()
    }


PLACEMENTS = {
    "shared": (False, False),
    "own-core": (True, False),
    "own-core-keep-alive": (True, True),
}
"""Where moto runs and which server: (on a core of its own, behind waitress with keep-alive)."""


def placement_words(store_core: int | None, keep_alive: bool) -> str:
    server = "moto behind waitress (keep-alive)" if keep_alive else "moto_server (werkzeug)"
    if store_core is None:
        return f"{server}; every process on every core"
    return f"{server} on core {store_core}; web server and uploader on the others"


def ingest_rows(
    frames: list[tuple[str, bytes]], runs: int, store_core: int | None, keep_alive: bool
) -> list[list[str]]:
    """Ingest to home and to moto, measured in turn with the same placement: every process on
    every core, or the store on a core of its own (``store_core``; the web server and the
    uploader on the others, for home and S3 alike)."""
    others = os.sched_getaffinity(0) - {store_core} if store_core is not None else None
    with moto_server(store_core, keep_alive) as endpoint, on_cores(others):
        s3_env = {
            "WELDPOOL_STORAGE_URL": f"s3://{bucket(endpoint)}/lab",
            "WELDPOOL_S3_ENDPOINT_URL": endpoint,
        }
        rates = ingest_rates(frames, {"home": {}, "s3": s3_env}, runs)
    rows = []
    for (label, batch, clients), (rate, cpu, web, _) in rates.items():
        if label != "home":
            continue
        other, other_cpu, other_web, moto = rates[("s3", batch, clients)]
        rows.append(
            [
                placement_words(store_core, keep_alive),
                f"{batch} files × {clients}",
                f"{rate:.1f}",
                f"{other:.1f}",
                f"**{other / rate:.2f}×**",
                f"{web:.1f}",
                f"{other_web:.1f}",
                f"{other_web / web:.2f}×",
                f"{cpu:.1f}",
                f"{other_cpu:.1f}",
                f"{moto:.1f}",
            ]
        )
    return rows


def client_put_ms(
    frames: list[tuple[str, bytes]], endpoint: str, runs: int
) -> dict[str, tuple[float, float, float]]:
    """(wall ms, client CPU ms, server CPU ms) to put every frame into a bucket from 8 threads
    as ingest does (a conditional PUT carrying its claim), through boto3 and through the
    store's obstore client (``app/storage/s3/uploads.py``), medians of runs."""
    from app.core.config import StoreWaits
    from app.storage.s3 import uploads
    from app.storage.s3.bucket import client_for

    name = bucket(endpoint)
    waits = StoreWaits(connect_s=3.0, read_s=60.0, attempts=1)
    boto = client_for(endpoint, "us-east-1", waits)

    def boto3_put(key: str, data: bytes) -> None:
        claimed = {"claimed": str(time.time_ns())}
        boto.put_object(Bucket=name, Key=key, Body=data, Metadata=claimed, IfNoneMatch="*")

    def obstore_put(key: str, data: bytes) -> None:
        uploads.create(boto, name, key, data, time.time_ns(), waits)

    clients = {"boto3": boto3_put, "obstore (what ingest uses)": obstore_put}
    timings: dict[str, list[tuple[float, float, float]]] = {}
    with ThreadPoolExecutor(8) as pool:
        for run in range(runs):
            for label, put in clients.items():
                server, client = server_cpu_s(), time.process_time()
                start = time.perf_counter()
                keys = [(f"{label}/{run}/{n}", d) for n, d in frames]
                list(pool.map(lambda item, p=put: p(*item), keys))
                wall = (time.perf_counter() - start) * 1000
                used = ((time.process_time() - client) * 1000, (server_cpu_s() - server) * 1000)
                timings.setdefault(label, []).append((wall, *used))
    return {
        label: tuple(statistics.median(v[i] for v in values) for i in range(3))  # type: ignore[misc]
        for label, values in timings.items()
    }


def click_reads(endpoint: str, frame: bytes) -> list[tuple[str, int, float]]:
    """Object reads of clicks in a web process with a cold cache (the frame stored by another)."""
    import torch
    from fastapi.testclient import TestClient
    from transformers import Sam2Config, Sam2Model

    from app.core.config import Settings
    from app.main import create_app
    from app.storage import open_storage

    url = f"s3://{bucket(endpoint)}/lab"
    rows = []
    with tempfile.TemporaryDirectory() as root:
        torch.manual_seed(0)
        Sam2Model(Sam2Config()).save_pretrained(Path(root) / "sam2")
        database = f"sqlite:///{Path(root) / 'shared.sqlite3'}"
        common = {
            "database_url": database,
            "storage_url": url,
            "s3_endpoint_url": endpoint,
            "sam2": str(Path(root) / "sam2"),
            "device": "cpu",
            "log_level": "WARNING",
        }
        writer = Settings(_env_file=None, home=Path(root) / "writer", **common)  # type: ignore[call-arg]
        reader = Settings(_env_file=None, home=Path(root) / "reader", **common)  # type: ignore[call-arg]
        headers = {"Authorization": f"Bearer {admin_token(database)}"}
        with TestClient(create_app(writer)) as http:
            upload = [("files", ("frame.png", frame, "image/png"))]
            frame_id = http.post("/api/v1/frames", files=upload, headers=headers).json()["stored"][
                0
            ]["id"]
        store = open_storage(reader, for_requests=True)  # the web process's own store
        with TestClient(create_app(reader)) as http:
            for label in ("first click, cold cache", "second click"):
                before = store.reads  # type: ignore[attr-defined]
                start = time.perf_counter()
                answer = http.post(
                    f"/api/v1/frames/{frame_id}/segment",
                    json={"points": [{"x": 640, "y": 400}]},
                    headers=headers,
                )
                answer.raise_for_status()
                elapsed = (time.perf_counter() - start) * 1000
                rows.append((label, store.reads - before, elapsed))  # type: ignore[attr-defined]
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--skip", nargs="*", default=(), choices=(*PLACEMENTS, "clients", "click"))
    args = parser.parse_args()
    if REAL_FRAMES.is_dir():
        frames = [(p.name, p.read_bytes()) for p in sorted(REAL_FRAMES.glob("*.png"))]
        name = "62 real WAAM frames"
    else:
        print(f"({REAL_FRAMES} is absent: 62 generated frames instead)")
        frames, name = generated_frames(62), "62 generated frames"
    size = sum(len(d) for _, d in frames) / len(frames) / 1024
    name = f"{name} ({size:.0f} KiB)"
    print(
        f"POST /api/v1/frames, median of {args.runs} runs; S3: moto's server on loopback. "
        "CPU: ms a frame of the web server process, and of every process on this machine "
        "(the web server, the uploader and, for S3, moto, whose share is given)"
    )
    cores = os.sched_getaffinity(0)
    rows = [
        row
        for label, (own_core, keep_alive) in PLACEMENTS.items()
        if label not in args.skip and (len(cores) > 1 or not own_core)
        for row in ingest_rows(frames, args.runs, max(cores) if own_core else None, keep_alive)
    ]
    if rows:
        columns = [
            f"{name}: where the S3 server runs",
            "files a request × clients",
            "home frames/s",
            "S3 frames/s",
            "S3 / home (goal ≥ 0.7×)",
            "web server CPU ms a frame, home",
            "S3",
            "S3 / home",
            "machine CPU ms a frame, home",
            "S3",
            "of it moto",
        ]
        print(Table(columns[0], columns, rows, ["left"] * 2 + ["right"] * 9).markdown() + "\n")
    with moto_server() as endpoint:
        if "clients" not in args.skip:
            puts = client_put_ms(frames, endpoint, args.runs)
            rows = [
                [label, f"{ms:.1f}", f"{len(frames) / ms * 1000:.1f}", f"{cpu:.0f}", f"{moto:.0f}"]
                for label, (ms, cpu, moto) in puts.items()
            ]
            columns = [
                f"{len(frames)} frames put into a bucket from 8 threads, median of {args.runs}",
                "ms",
                "frames/s",
                "client CPU ms",
                "moto CPU ms",
            ]
            print(Table(columns[0], columns, rows).markdown() + "\n")
        if "click" not in args.skip:
            frame = frames[len(frames) // 2][1]
            rows = [
                [label, str(reads), f"{ms:.0f}"]
                for label, reads, ms in click_reads(endpoint, frame)
            ]
            columns = [
                "a click in a web process with a cold cache (the frame stored by another "
                f"process; sha {hashlib.sha256(frame).hexdigest()[:8]}, full-size random SAM2)",
                "object reads",
                "ms",
            ]
            print(Table(columns[0], columns, rows).markdown())


if __name__ == "__main__":
    with recorded(__file__):
        main()
