"""Benchmark how quickly `weldpool serve` is healthy and how much memory it holds when idle.

Run: ``.venv/bin/python bench/serve_start.py [--runs 5]`` (about three minutes).

Each run starts `weldpool serve` (``--no-worker``, and with its embedded worker) on a fresh
SQLite home (the first start, which also creates the admin: on an empty home, where it makes the
schema too, and after `weldpool migrate`) or restarts it on a home an earlier start prepared,
polls ``/api/v1/health`` every 20 ms, and reads the process's resident memory (VmRSS) after a
second of idling. The floor is a bare ``python -c "import fastapi, sqlalchemy,
uvicorn"``: what any FastAPI service on this machine pays before its own code, measured just
before each start (the ratio is the median of the pairs'). Median of the runs.

Both run as on a user's machine, where Python keeps the bytecode it compiles: this sandbox sets
``PYTHONDONTWRITEBYTECODE``, which would make every start compile weldpool's own modules again
(site-packages were compiled at install), so the bench keeps bytecode in a folder of its own
(``PYTHONPYCACHEPREFIX``) and warms it with one start before measuring.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from results import recorded

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, free_port


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


BYTECODE = Path(tempfile.gettempdir()) / "weldpool-bench-bytecode"


def python_env(**extra: str) -> dict[str, str]:
    """The environment of a user's shell: bytecode kept (in a folder of the bench's own)."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("WELDPOOL_") and k != "PYTHONDONTWRITEBYTECODE"
    }
    env.update(PYTHONPYCACHEPREFIX=str(BYTECODE), HF_HUB_OFFLINE="1", **extra)
    return env


def one_start(worker: bool, restart: bool = False, migrated: bool = True) -> tuple[float, float]:
    """Seconds from ``serve`` to a healthy answer, and the idle RSS in MB; on a fresh home (the
    first start creates the admin, an Argon2 hash), migrated by ``weldpool migrate`` first unless
    ``migrated`` is False (then the start makes the schema too: the README's first command on a
    new machine), or, with ``restart``, the second start on a home the first one prepared (what
    a restart behind a load balancer pays)."""
    with tempfile.TemporaryDirectory() as home:
        env = python_env(WELDPOOL_HOME=home, WELDPOOL_LOG_LEVEL="WARNING")
        if migrated:
            subprocess.run(
                [sys.executable, "-m", "app", "migrate"],
                env=env,
                cwd=REPO,
                check=True,
                capture_output=True,
            )
        if restart:
            _serve(env, worker, idle=0.0)
        return _serve(env, worker, idle=1.0)


def _serve(env: dict[str, str], worker: bool, idle: float) -> tuple[float, float]:
    port = free_port()
    command = [sys.executable, "-m", "app", "serve", "--port", str(port)]
    start = time.perf_counter()
    server = subprocess.Popen(
        command + ([] if worker else ["--no-worker"]),
        env=env,
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).status_code:
                    break
            except httpx.HTTPError:
                time.sleep(0.02)
        healthy = time.perf_counter() - start
        time.sleep(idle)
        return healthy, rss_mb(server.pid)
    finally:
        server.terminate()
        server.wait(timeout=30)


def floor() -> float:
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import fastapi, sqlalchemy, uvicorn"], env=python_env(), check=True
    )
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    floor(), one_start(True)  # bytecode written once, as a first start on any machine does
    print("| serve | start to healthy s | idle RSS MB | floor s | start ÷ floor |")
    print("|---|---:|---:|---:|---:|")
    floors = []
    cases = {
        "first start on an empty home": (False, False),
        "first start after `weldpool migrate`": (False, True),
        "restart": (True, True),
    }
    for worker in (False, True):
        for case, (restart, migrated) in cases.items():
            runs, ratios = [], []
            for _ in range(args.runs):  # the floor beside each start: this machine drifts
                floors.append(floor())
                runs.append(one_start(worker, restart, migrated))
                ratios.append(runs[-1][0] / floors[-1])
            start = statistics.median(r[0] for r in runs)
            rss = statistics.median(r[1] for r in runs)
            name = ("embedded worker" if worker else "--no-worker") + f", {case}"
            beside = statistics.median(floors[-args.runs :])
            print(
                f"| {name} | {start:.2f} | {rss:.0f} | {beside:.2f} | "
                f"{statistics.median(ratios):.1f}× |",
                flush=True,
            )
    print(
        f"\nfloor (python -c 'import fastapi, sqlalchemy, uvicorn'): median "
        f"{statistics.median(floors):.2f} s; each ratio is the median of start ÷ the floor "
        "measured just before it"
    )


if __name__ == "__main__":
    with recorded(__file__):
        main()
