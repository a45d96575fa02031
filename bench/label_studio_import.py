"""Label Studio's import of the same labels as ``bench/label_import.py``'s, for the paired ratio.

Run with Label Studio's own environment (not weldpool's):
``/work/ls-venv/bin/python bench/label_studio_import.py [--frames 1000] [--runs 3]`` after
``python3 -m venv /work/ls-venv && /work/ls-venv/bin/pip install label-studio==1.23.2``.

It makes the 1,000 pool masks ``bench/label_import.py`` makes (same generator, same seed), as
Label Studio's brush RLE (``label_studio_sdk.converter.brush.mask2rle``, done before timing),
starts ``label-studio`` on a fresh data folder (SQLite), and times ``POST
/api/projects/{id}/import`` of one JSON task per frame with its annotation (the image as a URL
Label Studio does not fetch at import), until the import is complete. Median of ``--runs``, a
fresh project each.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
from label_studio_sdk.converter.brush import mask2rle
from results import Table, record

TOKEN = "0123456789abcdef0123456789abcdef01234567"
CONFIG = (
    '<View><Image name="image" value="$image"/><BrushLabels name="tag" toName="image">'
    '<Label value="weld_pool"/></BrushLabels></View>'
)


def _mask(rng: np.random.Generator) -> np.ndarray:  # bench/label_import.py's
    mask = np.zeros((800, 1280), np.uint8)
    centre = (int(rng.integers(500, 800)), int(rng.integers(350, 450)))
    axes = (int(rng.integers(250, 400)), int(rng.integers(100, 180)))
    cv2.ellipse(mask, centre, axes, float(rng.uniform(-10, 10)), 0, 360, 1, -1)
    cv2.rectangle(mask, (centre[0] + axes[0] - 60, centre[1] - 20), (1280, centre[1]), 0, -1)
    return mask > 0


def _call(url: str, method: str = "GET", body: object = None) -> object:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, method=method)
    request.add_header("Authorization", f"Token {TOKEN}")
    request.add_header("Content-Type", "application/json")
    with urllib.request.urlopen(request, timeout=600) as response:
        return json.loads(response.read() or b"null")


def _import(base: str, tasks: list[dict]) -> float:
    project = _call(f"{base}/api/projects", "POST", {"title": "bench", "label_config": CONFIG})
    start = time.perf_counter()
    answer = _call(f"{base}/api/projects/{project['id']}/import", "POST", tasks)
    if isinstance(answer, dict) and answer.get("import") is not None:  # asynchronous import
        while _call(f"{base}/api/projects/{project['id']}/imports/{answer['import']}")[
            "status"
        ] not in ("completed", "failed"):
            time.sleep(0.05)
    elapsed = time.perf_counter() - start
    tasks_here = _call(f"{base}/api/projects/{project['id']}")["task_number"]
    assert tasks_here == len(tasks), (tasks_here, answer)
    if isinstance(answer, dict) and "annotation_count" in answer:
        assert answer["annotation_count"] == len(tasks), answer
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--port", type=int, default=8089)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    tasks = []
    for index in range(args.frames):
        rle = mask2rle(_mask(rng).astype(np.uint8) * 255)
        value = {"format": "rle", "rle": rle, "brushlabels": ["weld_pool"]}
        result = {
            "from_name": "tag",
            "to_name": "image",
            "type": "brushlabels",
            "original_width": 1280,
            "original_height": 800,
            "value": value,
        }
        tasks.append(
            {
                "data": {"image": f"http://example.invalid/f{index:05d}.png"},
                "annotations": [{"result": [result]}],
            }
        )
    data = Path(tempfile.mkdtemp())
    environment = os.environ | {
        "LABEL_STUDIO_BASE_DATA_DIR": str(data),
        "LABEL_STUDIO_ENABLE_LEGACY_API_TOKEN": "true",  # the --user-token below
    }
    command = [
        str(Path(sys.executable).with_name("label-studio")),
        *("start", "--no-browser", "--port", str(args.port), "--data-dir", str(data)),
        *("--username", "bench@example.com", "--password", "bench-bench"),
        *("--user-token", TOKEN),
    ]
    server = subprocess.Popen(
        command, env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    base = f"http://127.0.0.1:{args.port}"
    try:
        for _ in range(1200):
            try:
                urllib.request.urlopen(f"{base}/health", timeout=2)
                break
            except OSError:
                time.sleep(0.5)
        times = [_import(base, tasks) for _ in range(args.runs)]
    finally:
        server.terminate()
        server.wait(timeout=30)
        shutil.rmtree(data, ignore_errors=True)
    seconds = statistics.median(times)
    table = Table(
        f"Label Studio 1.23.2 import, {args.frames} labels",
        [f"Label Studio 1.23.2 import, {args.frames} labels", "s", "frames/s", "runs s"],
        [
            [
                "JSON tasks with brush-RLE annotations, SQLite",
                f"{seconds:.2f}",
                f"{args.frames / seconds:.0f}",
                ", ".join(f"{t:.2f}" for t in times),
            ]
        ],
    )
    print(table.markdown())
    command = ["/work/ls-venv/bin/python", "bench/label_studio_import.py", *sys.argv[1:]]
    print(f"written to {record('bench/label_studio_import.py', [table], shlex.join(command))}")


if __name__ == "__main__":
    main()
