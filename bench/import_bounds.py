"""Benchmark what hostile or extreme label files cost to read (issue 53, items 1–3).

Run: ``PYTHONPATH=. .venv/bin/python bench/import_bounds.py [--scale 1.0]``

Each case's file is made beforehand; a fresh process then reads it as an import does (the
reader, then the label's content on a 1280×800 frame; for the zip, its first batch of mask
files), and the table gives the wall time and how far that process's peak RSS (``VmHWM``, reset
after the imports) rose above its RSS then. Linux only. A case that is refused says so. ``--scale``
shrinks the cases (the issue's sizes at 1.0) to measure the old code without waiting minutes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any

from results import Table, record

HEIGHT, WIDTH = 800, 1280
CASES = ("yaml_aliases", "zip_of_1mib_masks", "cvat_2m_points", "coco_keypoints", "tiny_polygons")


def _make_yaml_aliases(folder: Path, scale: float) -> None:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    (folder / "data.yaml").write_text("\n".join([*lines, "names: *a8"]))
    (folder / "labels").mkdir()
    (folder / "labels" / "f.txt").write_text("0 0.1 0.1 0.5 0.1 0.5 0.5\n")


def _read_yaml_aliases(folder: Path) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.yolo import read_yolo

    return read_yolo(open_source(folder), None)


def _make_zip_of_1mib_masks(folder: Path, scale: float) -> None:
    with zipfile.ZipFile(folder / "bomb.zip", "w", zipfile.ZIP_DEFLATED) as archive:
        for i in range(int(1500 * scale)):
            archive.writestr(f"masks/{i}.png", bytes(1 << 20))


def _read_zip_of_1mib_masks(folder: Path) -> object:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.masks import read_masks

    source = open_source(folder / "bomb.zip")
    parsed = read_masks(source, None)
    # What the first batch reads (the code before read every file in ``read_masks``).
    first = parsed.labels[:64]
    return [label.loaded(source) if hasattr(label, "loaded") else label for label in first]


def _make_cvat_2m_points(folder: Path, scale: float) -> None:
    count = int(2_000_000 * scale)
    points = ";".join(f"{100 + i % 1000}.5,{100 + (i // 1000) % 600}.5" for i in range(count))
    (folder / "annotations.xml").write_text(
        f'<annotations><image id="0" name="f.png" width="{WIDTH}" height="{HEIGHT}">'
        f'<polygon label="pool" points="{points}"/></image></annotations>'
    )


def _read_cvat_2m_points(folder: Path) -> object:
    from weldpool_core.annotations.cvat import read_cvat

    return _contents(folder, read_cvat)


def _contents(folder: Path, reader: Any) -> list[str | None]:
    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.content import label_content

    parsed = reader(open_source(folder), None)
    return [label_content(label, (HEIGHT, WIDTH), True).problem for label in parsed.labels]


def _make_coco_keypoints(folder: Path, scale: float) -> None:
    document = {
        "images": [{"id": 1, "file_name": "f.png", "width": WIDTH, "height": HEIGHT}],
        "categories": [{"id": 1, "name": "pool"}],
        "annotations": [
            {"id": i, "image_id": 1, "category_id": 1, "keypoints": [5, 5, 2]}
            for i in range(int(128_000 * scale))
        ],
    }
    (folder / "annotations.json").write_text(json.dumps(document))


def _read_coco_keypoints(folder: Path) -> object:
    from weldpool_core.annotations.coco import read_coco

    return _contents(folder, read_coco)


def _make_tiny_polygons(folder: Path, scale: float) -> None:
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


def _read_tiny_polygons(folder: Path) -> object:
    from weldpool_core.annotations.labelme import read_labelme

    return _contents(folder, read_labelme)


def _status_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def run_case(case: str, folder: Path) -> dict[str, object]:
    """One case in this process: seconds, peak RSS rise (MiB), outcome."""
    import weldpool_core.annotations  # noqa: F401  (imports before the baseline)
    from weldpool_core.errors import InvalidInputError
    from weldpool_core.lazy import cv2, np, yaml

    _ = (cv2.setNumThreads, np.zeros, yaml.safe_load)  # loaded before the baseline
    import pycocotools.mask  # noqa: F401

    Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) starts again from here
    before = _status_kib("VmRSS")
    start = time.perf_counter()
    try:
        result = globals()[f"_read_{case}"](folder)
        outcome = "read" if not isinstance(result, list) else f"{result}"[:60]
    except InvalidInputError as exc:
        outcome = f"refused: {exc.message}"[:60]
    seconds = time.perf_counter() - start
    peak = _status_kib("VmHWM")
    rise = (peak - before) // 1024
    return {"case": case, "s": round(seconds, 2), "rss_mib": rise, "outcome": outcome}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--case", choices=CASES)
    parser.add_argument("--folder", type=Path)
    parser.add_argument("--timeout", type=float, default=300)
    parser.add_argument("--only", nargs="*", choices=CASES, default=CASES)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case, args.folder)))
        return
    rows = []
    for case in args.only:
        with tempfile.TemporaryDirectory() as folder:
            globals()[f"_make_{case}"](Path(folder), args.scale)
            command = [sys.executable, __file__, "--case", case, "--folder", folder]
            done = _child(command, args.timeout)
        try:
            row = json.loads(done.stdout.strip().splitlines()[-1]) if done else {}
        except (IndexError, json.JSONDecodeError):
            row = {}
        if not row:
            row = {"case": case, "s": f">{args.timeout:g}", "rss_mib": "?", "outcome": "failed"}
        rows.append([str(row["case"]), str(row["s"]), str(row["rss_mib"]), str(row["outcome"])])
    table = Table(
        f"hostile file (scale {args.scale:g})",
        ["hostile file (scale)", "s", "+RSS MiB", "outcome"],
        rows,
        align=["left", "right", "right", "left"],
    )
    print(table.markdown())
    record(
        "bench/import_bounds.py",
        [table],
        f"PYTHONPATH=. .venv/bin/python bench/import_bounds.py --scale {args.scale:g}",
    )


def _child(command: list[str], timeout: float) -> subprocess.CompletedProcess[str] | None:
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None


if __name__ == "__main__":
    main()
