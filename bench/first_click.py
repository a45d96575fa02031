"""The first click on a frame: prepared while the review page is open, against the naive way.

Run: ``PYTHONPATH=. .venv/bin/python bench/first_click.py [--runs 3]``. In process (FastAPI's
TestClient, SQLite, the home folder), with SAM2 at its full size and random weights (the
product's architecture; the weights do not change the time). For each run a new 1280×800
frame is uploaded twice (two contents) and clicked:

- naive: the first click right away (it computes the frame's embedding), then a second click;
- prepared: ``POST /frames/{id}/embedding`` as the review page sends it when it opens, waited
  for (the page open for the embedding's time), then the first and second clicks; and the
  first click naming the stored mask it refines (``mask_from``) against sending it as a PNG.

Milliseconds a request takes as the client sees it, medians over the runs. Goal: the prepared
first click as fast as the second (ratio ≈ 1).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import cv2
from results import Table, record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()

    import torch
    from fastapi.testclient import TestClient
    from transformers import Sam2Config, Sam2Model

    from app.core.config import Settings
    from app.main import create_app
    from bench.common import admin_token
    from tests.helpers import corrected_label
    from weldpool_core.synth import SynthParams, synth_frame

    rows: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as root:
        torch.manual_seed(0)
        Sam2Model(Sam2Config()).save_pretrained(Path(root) / "sam2")
        settings = Settings(  # type: ignore[call-arg]
            _env_file=None,
            home=Path(root) / "home",
            sam2=str(Path(root) / "sam2"),
            device="cpu",
            log_level="WARNING",
            retrain_every=0,
        )
        headers = {"Authorization": f"Bearer {admin_token(settings.resolved_database_url)}"}
        click = {"points": [{"x": 640, "y": 400, "positive": True}]}

        def timed(http: TestClient, method: str, path: str, **kwargs: object) -> float:
            start = time.perf_counter()
            answer = http.request(method, path, headers=headers, **kwargs)  # type: ignore[arg-type]
            answer.raise_for_status()
            return (time.perf_counter() - start) * 1000

        with TestClient(create_app(settings, embedded_worker=False)) as http:
            for run in range(args.runs):
                ids = []
                for copy in range(2):
                    sample = synth_frame(seed=run * 2 + copy, params=SynthParams(1280, 800))
                    png = cv2.imencode(".png", sample.image)[1].tobytes()
                    upload = [("files", (f"f{run}-{copy}.png", png, "image/png"))]
                    stored = http.post("/api/v1/frames", files=upload, headers=headers).json()
                    ids.append(stored["stored"][0]["id"])
                    label = http.put(
                        f"/api/v1/frames/{ids[-1]}/label",
                        json=corrected_label(sample.mask),
                        headers=headers,
                    )
                    label.raise_for_status()
                naive, prepared = ids
                segment = f"/api/v1/frames/{naive}/segment"
                rows.setdefault("naive: first click", []).append(
                    timed(http, "POST", segment, json=click)
                )
                rows.setdefault("naive: second click", []).append(
                    timed(http, "POST", segment, json=click)
                )
                start = time.perf_counter()
                http.post(f"/api/v1/frames/{prepared}/embedding", headers=headers)
                while (
                    http.get(f"/api/v1/frames/{prepared}/embedding", headers=headers).json()[
                        "state"
                    ]
                    != "ready"
                ):
                    time.sleep(0.05)
                rows.setdefault("prepared: the embedding (page open)", []).append(
                    (time.perf_counter() - start) * 1000
                )
                segment = f"/api/v1/frames/{prepared}/segment"
                mask_png = http.get(f"/api/v1/frames/{prepared}/label", headers=headers).json()[
                    "mask_png"
                ]
                rows.setdefault("prepared: first click, mask named", []).append(
                    timed(http, "POST", segment, json={**click, "mask_from": {"label_revision": 1}})
                )
                rows.setdefault("prepared: second click, mask as PNG", []).append(
                    timed(http, "POST", segment, json={**click, "mask_png": mask_png})
                )
                rows.setdefault("prepared: third click, mask named", []).append(
                    timed(http, "POST", segment, json={**click, "mask_from": {"label_revision": 1}})
                )
    medians = {name: statistics.median(values) for name, values in rows.items()}
    later = medians["prepared: third click, mask named"]
    print(f"first click on a 1280×800 frame, full-size random SAM2 on CPU, median of {args.runs}")
    print(f"{'request':<40}{'ms':>10}{'× a later click':>17}")
    table = Table("request", ["request", "ms", "× a later click"], [])
    for name, ms in medians.items():
        print(f"{name:<40}{ms:>10.1f}{ms / later:>17.2f}")
        table.rows.append([name, f"{ms:.1f}", f"{ms / later:.2f}"])
    print(f"written to {record('bench/first_click.py', [table])}")


if __name__ == "__main__":
    main()
