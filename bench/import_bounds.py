"""Benchmark what hostile or extreme label files cost to read (issue 53, items 1–3).

Run: ``PYTHONPATH=. .venv/bin/python bench/import_bounds.py [--scale 1.0]``

Each case runs in a fresh process and reads its file as an import does (the reader, then the
label's content on a 1280×800 frame); the table gives the wall time and how far the process's
peak RSS rose above its state after imports. A case that is refused says so. ``--scale``
shrinks the cases (the issue's sizes at 1.0) to measure the old code without waiting minutes.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

HEIGHT, WIDTH = 800, 1280
CASES = ("yaml_aliases", "zip_of_1mib_masks", "cvat_2m_points", "coco_keypoints", "tiny_polygons")


def _yaml_aliases(folder: Path, scale: float) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.yolo import read_yolo

    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    (folder / "data.yaml").write_text("\n".join([*lines, "names: *a8"]))
    (folder / "labels").mkdir()
    (folder / "labels" / "f.txt").write_text("0 0.1 0.1 0.5 0.1 0.5 0.5\n")
    return read_yolo(open_source(folder), None)


def _zip_of_1mib_masks(folder: Path, scale: float) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.masks import read_masks

    path = folder / "bomb.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for i in range(int(1500 * scale)):
            archive.writestr(f"masks/{i}.png", bytes(1 << 20))
    parsed = read_masks(open_source(path), None)
    return parsed


def _cvat_2m_points(folder: Path, scale: float) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.content import label_content
    from weldpool_core.annotations.cvat import read_cvat

    count = int(2_000_000 * scale)
    points = ";".join(f"{100 + i % 1000}.5,{100 + (i // 1000) % 600}.5" for i in range(count))
    (folder / "annotations.xml").write_text(
        f'<annotations><image id="0" name="f.png" width="{WIDTH}" height="{HEIGHT}">'
        f'<polygon label="pool" points="{points}"/></image></annotations>'
    )
    parsed = read_cvat(open_source(folder), None)
    return [label_content(label, (HEIGHT, WIDTH), True).problem for label in parsed.labels]


def _coco_keypoints(folder: Path, scale: float) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.coco import read_coco
    from weldpool_core.annotations.content import label_content

    document = {
        "images": [{"id": 1, "file_name": "f.png", "width": WIDTH, "height": HEIGHT}],
        "categories": [{"id": 1, "name": "pool"}],
        "annotations": [
            {"id": i, "image_id": 1, "category_id": 1, "keypoints": [5, 5, 2]}
            for i in range(int(128_000 * scale))
        ],
    }
    (folder / "annotations.json").write_text(json.dumps(document))
    parsed = read_coco(open_source(folder), None)
    return [label_content(label, (HEIGHT, WIDTH), True).problem for label in parsed.labels]


def _tiny_polygons(folder: Path, scale: float) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.content import label_content
    from weldpool_core.annotations.labelme import read_labelme

    shapes = [
        {
            "label": "pool",
            "shape_type": "polygon",
            "points": [[x, y], [x + 3, y], [x + 3, y + 3]],
        }
        for x in range(0, WIDTH - 4, 8)
        for y in range(0, HEIGHT - 4, 8)
    ][: int(16_000 * scale)]
    document = {"shapes": shapes, "imagePath": "f.png", "imageHeight": HEIGHT, "imageWidth": WIDTH}
    (folder / "f.json").write_text(json.dumps(document))
    parsed = read_labelme(open_source(folder), None)
    return [label_content(label, (HEIGHT, WIDTH), True).problem for label in parsed.labels]


def run_case(case: str, scale: float) -> dict[str, object]:
    """One case in this process: seconds, peak RSS rise (MiB), outcome."""
    import weldpool_core.annotations  # noqa: F401  (imports before the baseline)
    from weldpool_core.errors import InvalidInputError
    from weldpool_core.lazy import cv2, np, yaml

    _ = (cv2.setNumThreads, np.zeros, yaml.safe_load)  # loaded before the baseline
    import pycocotools.mask  # noqa: F401

    with tempfile.TemporaryDirectory() as folder:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        start = time.perf_counter()
        try:
            result = globals()[f"_{case}"](Path(folder), scale)
            outcome = "read" if not isinstance(result, list) else f"{result}"[:60]
        except InvalidInputError as exc:
            outcome = f"refused: {exc.message}"[:60]
        seconds = time.perf_counter() - start
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rise = (peak - before) // 1024
    return {"case": case, "s": round(seconds, 2), "rss_mib": rise, "outcome": outcome}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--case", choices=CASES)
    parser.add_argument("--timeout", type=float, default=300)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case, args.scale)))
        return
    print(f"{'case':20} {'seconds':>8} {'+RSS MiB':>9}  outcome (scale {args.scale})")
    for case in CASES:
        command = [sys.executable, __file__, "--case", case, "--scale", str(args.scale)]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=args.timeout)
            row = json.loads(done.stdout.strip().splitlines()[-1])
        except subprocess.TimeoutExpired:
            row = {"case": case, "s": f">{args.timeout:g}", "rss_mib": "?", "outcome": "timeout"}
        except (IndexError, json.JSONDecodeError):
            row = {"case": case, "s": "?", "rss_mib": "?", "outcome": done.stderr[-60:]}
        print(f"{row['case']:20} {row['s']:>8} {row['rss_mib']:>9}  {row['outcome']}")


if __name__ == "__main__":
    main()
