"""A reviewer's clicks while the same machine trains the student and runs the teacher.

Run: ``PYTHONPATH=. .venv/bin/python bench/interactive.py [--clicks 40] [--epochs 30]`` (about
10 minutes on 2 cores; run it alone: it measures contention, so nothing else may compete).

For each budget — ``nice`` (the defaults: a click's own threads, job threads niced), ``on`` (also
fewer job threads while a reviewer is active) and ``off`` (every thread for everyone at one
priority, as before the budgets) — a throw-away ``weldpool serve`` with its embedded worker (one
job at a time, the default; ``--workers 2`` runs both jobs at once) and full-size random-weight
SAM2 and DINO gets ``weldpool demo``'s synthetic run and a real 1280×800 WAAM frame to click on
(its embedding made first). Then:

1. **quiet**: clicks, one at a time, with a reviewer's pause (``--think`` s) between them;
2. **training alone**: a training job (``--epochs``), no clicks: its wall time (the job's
   started_at to finished_at);
3. **loaded**: the same training job and a teacher job on ``--teacher-frames`` frames of the
   demo run queued behind it; clicks as in 1 throughout. Clicks are counted under training and
   under the teacher, and the training's wall time is compared with 2.

Clicks are HTTP round trips (``POST /frames/{id}/segment``, one point) in milliseconds.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
from results import recorded

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED_DATA, local_server

BUDGETS = {
    "nice": {},  # the defaults: interactive threads, job threads niced
    "on": {"WELDPOOL_REVIEWER_ACTIVE_S": "20"},  # and jobs give up threads while a reviewer clicks
    "off": {
        "WELDPOOL_INTERACTIVE_THREADS": "2",
        "WELDPOOL_BATCH_NICE": "0",
        "WELDPOOL_REVIEWER_ACTIVE_S": "0",
    },
}


def _frame_png() -> bytes:
    frames = sorted((SHARED_DATA / "waam" / "frames").glob("*.png"))
    if frames:
        return frames[len(frames) // 2].read_bytes()
    import cv2

    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.integers(0, 255, (800, 1280), dtype=np.uint8), (0, 0), 9)
    return bytes(cv2.imencode(".png", image)[1].tobytes())


def _weights(root: Path) -> dict[str, str]:
    import torch
    from transformers import Sam2Config, Sam2Model

    from weldpool_core.teacher.dino import DinoAttention, dino_vits8_config

    torch.manual_seed(0)
    Sam2Model(Sam2Config()).save_pretrained(root / "sam2")
    DinoAttention.from_config(dino_vits8_config(), 480, "cpu").model.save_pretrained(root / "dino")
    return {"WELDPOOL_SAM2": str(root / "sam2"), "WELDPOOL_DINO": str(root / "dino")}


def _wall_s(job: dict) -> float:
    started = dt.datetime.fromisoformat(job["started_at"])
    return (dt.datetime.fromisoformat(job["finished_at"]) - started).total_seconds()


class Reviewer:
    def __init__(self, http: httpx.Client, frame_id: int, think_s: float) -> None:
        self.http, self.frame_id, self.think_s = http, frame_id, think_s
        self.rng = np.random.default_rng(0)

    def click(self) -> float:
        point = {"x": int(self.rng.integers(400, 880)), "y": int(self.rng.integers(250, 550))}
        start = time.perf_counter()
        answer = self.http.post(f"/api/v1/frames/{self.frame_id}/segment", json={"points": [point]})
        answer.raise_for_status()
        elapsed = (time.perf_counter() - start) * 1000
        time.sleep(self.think_s)
        return elapsed

    def clicks_until(self, done, limit: int | None = None) -> list[float]:  # type: ignore[no-untyped-def]
        times: list[float] = []
        while not done() and (limit is None or len(times) < limit):
            times.append(self.click())
        return times


def _job(http: httpx.Client, job_id: int) -> dict:
    return http.get(f"/api/v1/jobs/{job_id}").json()


def _finished(http: httpx.Client, job_id: int) -> bool:
    status = _job(http, job_id)["status"]
    if status in ("failed", "cancelled"):
        raise RuntimeError(f"job {job_id} {status}: {_job(http, job_id)['error']}")
    return status == "succeeded"


def _wait(http: httpx.Client, job_id: int) -> dict:
    while not _finished(http, job_id):
        time.sleep(0.5)
    return _job(http, job_id)


def _percentiles(times: list[float]) -> tuple[float, float]:
    return float(np.percentile(times, 50)), float(np.percentile(times, 95))


def one_budget(name: str, weights: dict[str, str], args: argparse.Namespace) -> dict:
    """Quiet clicks, training alone, then training and teacher under clicks, on one server."""
    env = {**weights, **BUDGETS[name], "WELDPOOL_WORKERS": str(args.workers)}
    setup = [("demo", "--frames", "24")]
    with (
        local_server(env, setup=setup) as (url, token),
        httpx.Client(
            base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=600
        ) as http,
    ):
        runs = http.get("/api/v1/sequences").json()
        demo_run = next(r for r in runs if r["name"].startswith("demo"))
        demo_frames = http.get(
            "/api/v1/frames", params={"sequence_id": demo_run["id"], "limit": 100}
        ).json()["items"]
        upload = [("files", ("real.png", _frame_png(), "image/png"))]
        stored = http.post("/api/v1/frames", files=upload).json()
        reviewer = Reviewer(http, stored["stored"][0]["id"], args.think)
        reviewer.click()  # its embedding, made once
        quiet = [reviewer.click() for _ in range(args.clicks)]
        train = {"epochs": args.epochs}
        alone = _wait(http, http.post("/api/v1/student/train", json=train).json()["job_id"])
        training = http.post("/api/v1/student/train", json=train).json()["job_id"]
        teacher_frames = [f["id"] for f in demo_frames[: args.teacher_frames]]
        teacher = http.post(
            "/api/v1/teacher/runs", json={"frame_ids": teacher_frames, "force": True}
        ).json()["job_id"]
        while _job(http, training)["status"] == "queued":
            time.sleep(0.05)
        under_training = reviewer.clicks_until(lambda: _finished(http, training))
        while _job(http, teacher)["status"] == "queued":  # (with 2 workers: already running)
            time.sleep(0.05)
        under_teacher = reviewer.clicks_until(lambda: _finished(http, teacher))
        loaded = _job(http, training)
        return {
            "quiet": _percentiles(quiet),
            "training": _percentiles(under_training),
            "teacher": _percentiles(under_teacher),
            "clicks": (len(quiet), len(under_training), len(under_teacher)),
            "train_alone_s": _wall_s(alone),
            "train_loaded_s": _wall_s(loaded),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clicks", type=int, default=40)
    parser.add_argument("--think", type=float, default=1.0)
    parser.add_argument("--epochs", type=int, default=120)
    parser.add_argument("--teacher-frames", type=int, default=6)
    parser.add_argument("--workers", type=int, default=1, help="2: both jobs at once")
    parser.add_argument(
        "--budgets", nargs="+", default=["off", "nice", "on"], choices=list(BUDGETS)
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as root:
        weights = _weights(Path(root))
        rows = {}
        for name in args.budgets:
            rows[name] = one_budget(name, weights, args)
            print(f"budgets {name}: {rows[name]}", file=sys.stderr, flush=True)
    print(
        "| budgets | click quiet p50 / p95 ms | under training p50 / p95 | under teacher p50 / p95 "
        "| p95 loaded ÷ quiet (training, teacher) | training alone s | training under clicks s "
        "| ÷ |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, row in rows.items():
        quiet, training, teacher = row["quiet"], row["training"], row["teacher"]
        print(
            f"| {name} | {quiet[0]:.0f} / {quiet[1]:.0f} | {training[0]:.0f} / {training[1]:.0f} "
            f"| {teacher[0]:.0f} / {teacher[1]:.0f} | {training[1] / quiet[1]:.2f}×, "
            f"{teacher[1] / quiet[1]:.2f}× | {row['train_alone_s']:.1f} | "
            f"{row['train_loaded_s']:.1f} | {row['train_loaded_s'] / row['train_alone_s']:.2f}× |"
        )
    print(
        "\nclicks counted (quiet, under training, under teacher): "
        + "; ".join(f"{n} {r['clicks']}" for n, r in rows.items())
    )


if __name__ == "__main__":
    with recorded(__file__):
        main()
