"""One teacher run on one worker and on two: the fan-out's speed-up (goal ≥ 1.7× on 2 workers).

Full-size DINO ViT-S/8 and SAM2 hiera-tiny with random weights, saved as local folders; N
frames of 640×400 uploaded to a throw-away home (SQLite, the SQLite queue); then for 1 and 2
`weldpool worker` processes (one model thread each, one torch thread each) a forced teacher run
over the frames, timed from the request to its end, median of runs. Each worker loads the
teacher once before its timing starts (a warm-up run). Prints the table and records it
(``docs/benchmarks/fanout.json``).

    PYTHONPATH=. .venv/bin/python bench/fanout.py [--frames 12] [--runs 2]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
from common import REPO, local_server
from results import Table, record

WEIGHTS_ENV = ("WELDPOOL_DINO", "WELDPOOL_SAM2")


def _save_teacher(directory: Path) -> dict[str, str]:
    from transformers import Sam2Config, Sam2Model, ViTModel

    from weldpool_core.teacher.dino import dino_vits8_config

    ViTModel(dino_vits8_config(), add_pooling_layer=False).save_pretrained(directory / "dino")
    Sam2Model(Sam2Config()).save_pretrained(directory / "sam2")
    return {"WELDPOOL_DINO": str(directory / "dino"), "WELDPOOL_SAM2": str(directory / "sam2")}


def _png(seed: int) -> bytes:
    import cv2

    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 60, (400, 640, 3), dtype=np.uint8)
    cv2.ellipse(frame, (320, 200), (90, 50), 0, 0, 360, (250, 250, 250), -1)
    return cv2.imencode(".png", frame)[1].tobytes()


def _run(url: str, token: str, frame_ids: list[int]) -> float:
    headers = {"Authorization": f"Bearer {token}"}
    start = time.perf_counter()
    job = httpx.post(
        f"{url}/api/v1/teacher/runs",
        json={"frame_ids": frame_ids, "force": True},
        headers=headers,
        timeout=30,
    ).json()["job_id"]
    while True:
        state = httpx.get(f"{url}/api/v1/jobs/{job}", headers=headers, timeout=30).json()
        if state["status"] in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.2)
    if state["status"] != "succeeded":
        raise SystemExit(f"the teacher run ended {state['status']}: {state['error']}")
    return time.perf_counter() - start


def _workers(env: dict[str, str], count: int) -> list[subprocess.Popen[bytes]]:
    return [
        subprocess.Popen(
            [sys.executable, "-m", "app", "worker", "--lanes", "model", "--threads", "1"],
            env=env,
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for _ in range(count)
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(
            os.environ,
            WELDPOOL_HOME=str(Path(tmp) / "home"),
            WELDPOOL_LOG_LEVEL="WARNING",
            WELDPOOL_BATCH_THREADS="1",
            HF_HUB_OFFLINE="1",
            **_save_teacher(Path(tmp) / "weights"),
        )
        with local_server(env, worker=False, setup=[("migrate",)]) as (url, token):
            files = [("files", (f"{i}.png", _png(i), "image/png")) for i in range(args.frames)]
            stored = httpx.post(
                f"{url}/api/v1/frames",
                files=files,
                headers={"Authorization": f"Bearer {token}"},
                timeout=120,
            ).json()["stored"]
            frame_ids = [frame["id"] for frame in stored]
            for count in (1, 2):
                workers = _workers(env, count)
                try:
                    _run(url, token, frame_ids[: 4 * count])  # loads the teacher in each
                    times = [_run(url, token, frame_ids) for _ in range(args.runs)]
                finally:
                    for worker in workers:
                        worker.send_signal(signal.SIGTERM)
                        worker.wait(timeout=60)
                rows.append((count, statistics.median(times), times))
    base = rows[0][1]
    table = Table(
        f"teacher run of {args.frames} frames (640×400, full-size random teacher, CPU)",
        ["workers", "median s", "runs s", "frames/s", "speed-up"],
        [
            [
                str(count),
                f"{median:.1f}",
                " ".join(f"{t:.1f}" for t in times),
                f"{args.frames / median:.3f}",
                f"{base / median:.2f}×",
            ]
            for count, median, times in rows
        ],
        align=["right"] * 5,
    )
    print(table.markdown())
    record(
        "bench/fanout.py",
        [table],
        f"PYTHONPATH=. .venv/bin/python bench/fanout.py --frames {args.frames} --runs {args.runs}",
    )


if __name__ == "__main__":
    main()
