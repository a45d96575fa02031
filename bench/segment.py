"""HTTP round trip of a click: POST /api/v1/frames/{id}/segment on a warm embedding cache.

Starts a throw-away `weldpool serve` whose SAM2 is the full-size sam2.1-hiera-tiny architecture
with random weights (saved to a temporary directory), uploads a 1280×800 frame (a real WAAM frame
when ../shared is present), makes one click to compute and cache the embedding, then times 50
clicks from a client; compares with the decoder alone in-process.

    .venv/bin/python bench/segment.py [--clicks 50]
"""

from __future__ import annotations

import argparse
import shlex
import sys
import tempfile
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import torch
from common import SHARED_DATA, local_server
from results import Table, record

REAL_FRAMES = SHARED_DATA / "waam" / "frames"


def _frame_png() -> bytes:
    frames = sorted(REAL_FRAMES.glob("*.png")) if REAL_FRAMES.is_dir() else []
    if frames:
        return frames[len(frames) // 2].read_bytes()
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.integers(0, 255, (800, 1280), dtype=np.uint8), (0, 0), 9)
    return cv2.imencode(".png", image)[1].tobytes()


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.array(values), q))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clicks", type=int, default=50)
    args = parser.parse_args()
    from transformers import Sam2Config, Sam2Model

    with tempfile.TemporaryDirectory() as root:
        torch.manual_seed(0)
        Sam2Model(Sam2Config()).save_pretrained(Path(root) / "sam2")
        env = {"WELDPOOL_SAM2": str(Path(root) / "sam2"), "OMP_NUM_THREADS": "2"}
        with (
            local_server(env, worker=False) as (url, token),
            httpx.Client(
                base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=120
            ) as http,
        ):
            upload = [("files", ("frame.png", _frame_png(), "image/png"))]
            frame_id = http.post("/api/v1/frames", files=upload).json()["stored"][0]["id"]
            start = time.perf_counter()
            first = http.post(
                f"/api/v1/frames/{frame_id}/segment", json={"points": [{"x": 640, "y": 400}]}
            ).json()
            cold = time.perf_counter() - start
            rng = np.random.default_rng(1)
            round_trips, server_ms = [], []
            for _ in range(args.clicks):
                x, y = float(rng.uniform(100, 1180)), float(rng.uniform(100, 700))
                body = {"points": [{"x": x, "y": y}, {"x": 640, "y": 400}]}
                start = time.perf_counter()
                answer = http.post(f"/api/v1/frames/{frame_id}/segment", json=body).json()
                round_trips.append((time.perf_counter() - start) * 1000)
                server_ms.append(answer["elapsed_ms"])
                assert answer["embedding"] == "memory"

    from weldpool_core.teacher.sam2 import Prompts, Sam2Predictor

    torch.set_num_threads(2)
    predictor = Sam2Predictor.from_config(Sam2Config())
    image = cv2.cvtColor(cv2.imdecode(np.frombuffer(_frame_png(), np.uint8), 1), cv2.COLOR_BGR2RGB)
    embedding = predictor.set_image(image)
    decoder = []
    for _ in range(args.clicks):
        start = time.perf_counter()
        _ = predictor.predict(embedding, Prompts(((300.0, 300.0), (640.0, 400.0)), (1, 1))).mask
        decoder.append((time.perf_counter() - start) * 1000)

    print(
        f"\nclick on a 1280×800 frame, SAM2 hiera-tiny (random weights), CPU, {args.clicks} clicks"
    )
    print(f"{'measure':<44} {'p50 ms':>8} {'p95 ms':>8}")
    rows = [
        ("HTTP round trip (client)", round_trips),
        ("server time (elapsed_ms)", server_ms),
        ("decoder + upsampling alone (in-process)", decoder),
    ]
    table = Table("measure", ["measure", "p50 ms", "p95 ms"], [])
    for name, values in rows:
        print(f"{name:<44} {_percentile(values, 50):>8.1f} {_percentile(values, 95):>8.1f}")
        table.rows.append(
            [name, f"{_percentile(values, 50):.1f}", f"{_percentile(values, 95):.1f}"]
        )
    command = shlex.join([".venv/bin/python", "bench/segment.py", *sys.argv[1:]])
    print(f"written to {record('bench/segment.py', [table], command)}")
    print(
        f"first click (loads SAM2, encodes, caches): {cold:.1f} s; first answer's embedding: "
        f"{first['embedding']}"
    )


if __name__ == "__main__":
    main()
