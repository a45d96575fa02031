"""Object storage: ingest into an S3-protocol store against home, the S3 clients, and the
object reads of a click from a cold cache.

Starts moto's standalone S3 server on loopback (the one the tests use; MinIO or AWS are
faster), then:

1. ``POST /api/v1/frames`` of the 62 real WAAM frames (a throw-away `weldpool serve`, SQLite, no
   worker) on the home folder and on ``WELDPOOL_STORAGE_URL=s3://…``: frames/s, median of
   ``--runs``, and the ratio (goal ≥ 0.7×).
2. The same 62 frames put straight into a bucket from 8 threads with boto3 (what the store
   uses) and with obstore (when installed): the client's share of the time.
3. A click on a frame in a web process whose cache is cold (a fresh home, the frame written by
   another process): the object reads it makes (goal ≤ 1), and the second click's.

    .venv/bin/python bench/storage.py [--runs 5]
"""

from __future__ import annotations

import argparse
import hashlib
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

REAL_FRAMES = SHARED_DATA / "waam" / "frames"
os.environ.setdefault("AWS_ACCESS_KEY_ID", "bench")
os.environ.setdefault("AWS_SECRET_ACCESS_KEY", "bench")
os.environ.setdefault("AWS_REGION", "us-east-1")


SERVER_PID = 0


def server_cpu_s() -> float:
    """CPU seconds the S3 server process has used (it shares this machine's two cores)."""
    fields = Path(f"/proc/{SERVER_PID}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextmanager
def moto_server() -> Iterator[str]:
    global SERVER_PID
    port = free_port()
    server = Path(sys.executable).with_name("moto_server")
    process = subprocess.Popen(
        [str(server), "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
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
    frames: list[tuple[str, bytes]], env: dict[str, str], runs: int, salt: int
) -> dict[tuple[int, int], tuple[float, float, float]]:
    """(frames/s, machine CPU ms a frame, the S3 server's CPU ms a frame) for (files per
    request, clients): all in one request, half on each of two; medians of runs."""
    rates: dict[tuple[int, int], list[tuple[float, float, float]]] = {}
    configs = ((len(frames), 1), (-(-len(frames) // 2), 2))
    with local_server(env, worker=False) as (url, token):
        for run in range(runs):
            for batch, clients in configs:
                salted = _salted(frames, salt + run * 10 + clients)
                machine, server = machine_cpu_s(), server_cpu_s()
                rate = upload_run(url, token, salted, batch, clients, f"b-{time.time_ns()}")
                used = [
                    (f() - s) * 1000 / len(frames)
                    for f, s in ((machine_cpu_s, machine), (server_cpu_s, server))
                ]
                rates.setdefault((batch, clients), []).append((rate, *used))
    return {
        config: tuple(statistics.median(v[i] for v in values) for i in range(3))  # type: ignore[misc]
        for config, values in rates.items()
    }


def client_put_ms(
    frames: list[tuple[str, bytes]], endpoint: str, runs: int
) -> dict[str, tuple[float, float, float]]:
    """(wall ms, client CPU ms, server CPU ms) to put every frame into a bucket from 8 threads,
    per client, medians of runs."""
    import boto3
    from botocore.config import Config

    name = bucket(endpoint)
    boto = boto3.client("s3", endpoint_url=endpoint, config=Config(max_pool_connections=16))
    clients = {
        "boto3": lambda key, data: boto.put_object(Bucket=name, Key=key, Body=data),
    }
    try:
        import obstore
        from obstore.store import S3Store

        store = S3Store(
            name,
            endpoint=endpoint,
            region="us-east-1",
            access_key_id="bench",
            secret_access_key="bench",
            client_options={"allow_http": True},
        )
        clients["obstore"] = lambda key, data: obstore.put(store, key, data)
    except ImportError:
        print("(obstore is not installed: pip install obstore to compare it)")
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
        store = open_storage(reader)
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
    args = parser.parse_args()
    if REAL_FRAMES.is_dir():
        frames = [(p.name, p.read_bytes()) for p in sorted(REAL_FRAMES.glob("*.png"))]
        name = "62 real WAAM frames"
    else:
        print(f"({REAL_FRAMES} is absent: 62 generated frames instead)")
        frames, name = generated_frames(62), "62 generated frames"
    size = sum(len(d) for _, d in frames) / len(frames) / 1024
    with moto_server() as endpoint:
        local = ingest_rates(frames, {}, args.runs, 1000)
        s3_env = {
            "WELDPOOL_STORAGE_URL": f"s3://{bucket(endpoint)}/lab",
            "WELDPOOL_S3_ENDPOINT_URL": endpoint,
        }
        remote = ingest_rates(frames, s3_env, args.runs, 2000)
        print(
            f"\nPOST /api/v1/frames, {name} ({size:.0f} KiB each), median of {args.runs} runs; "
            "S3: moto's server on loopback"
        )
        cores = os.cpu_count() or 1
        print(
            f"CPU: ms a frame of every process on this machine ({cores} cores: the web process, "
            "the uploader, and for S3 the S3 server, whose share is given); ceiling: the S3 rate "
            "with every core busy, against home"
        )
        print(
            f"{'files/request':>13} {'clients':>7} {'home frames/s':>14} {'S3 frames/s':>12} "
            f"{'S3 / home':>10} {'home CPU':>9} {'S3 CPU':>7} {'of it S3 server':>16} "
            f"{'ceiling':>8}"
        )
        for (batch, clients), (rate, cpu, _) in local.items():
            other, other_cpu, server_cpu = remote[(batch, clients)]
            ceiling = cores * 1000 / other_cpu / rate
            print(
                f"{batch:>13} {clients:>7} {rate:>14.1f} {other:>12.1f} {other / rate:>9.2f}x "
                f"{cpu:>9.1f} {other_cpu:>7.1f} {server_cpu:>16.1f} {ceiling:>7.2f}x"
            )

        puts = client_put_ms(frames, endpoint, args.runs)
        print(f"\n{len(frames)} frames put into a bucket from 8 threads, median of {args.runs}")
        print(
            f"{'client':<8} {'ms':>8} {'frames/s':>9} {'client CPU ms':>14} {'server CPU ms':>14}"
        )
        for label, (ms, client_cpu, server_cpu) in puts.items():
            print(
                f"{label:<8} {ms:>8.1f} {len(frames) / ms * 1000:>9.1f} {client_cpu:>14.0f} "
                f"{server_cpu:>14.0f}"
            )

        frame = frames[len(frames) // 2][1]
        print(
            "\nA click in a web process with a cold cache (the frame stored by another process; "
            f"sha {hashlib.sha256(frame).hexdigest()[:8]}, full-size random SAM2)"
        )
        print(f"{'click':<26} {'object reads':>12} {'ms':>8}")
        for label, reads, ms in click_reads(endpoint, frame):
            print(f"{label:<26} {reads:>12} {ms:>8.0f}")


if __name__ == "__main__":
    main()
