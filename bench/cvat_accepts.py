"""Does a CVAT-for-images task of the original frames accept weldpool's CVAT export?

CVAT imports "CVAT for images 1.1" annotations onto a task by matching each ``<image name>`` to
the task's frames by file name without its extension (``match_frame`` in CVAT's
``dataset_manager/bindings.py``), and parses the XML with Datumaro, its own format library.
This script checks both on the 15 hand-labelled real frames (``data/waam/labels/``):

1. a throw-away ``weldpool serve`` gets the label configuration of issue 59 (pool, ``wire``
   mask, ``wire tip`` points, ``spatter`` instances with a ``size`` attribute, the frame tag
   ``arc unstable``), the 15 frames under their own names, each frame's real pool mask and
   objects of the other classes;
2. it exports CVAT;
3. Datumaro's ``cvat`` importer, run in an environment that has it (``--datumaro-python``, e.g.
   ``python3 -m venv /tmp/dm && /tmp/dm/bin/pip install datumaro``), loads the export; every
   item must match one original frame by CVAT's rule, and every shape, point, tag and attribute
   sent must be read back.

``python bench/cvat_accepts.py --datumaro-python /tmp/dm/bin/python``
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import subprocess
import sys
import tempfile
import zipfile
from collections import Counter
from pathlib import Path

import cv2
import httpx
import numpy as np
from common import SHARED_DATA, local_server
from results import recorded

CONFIG = {
    "version": 0,
    "classes": [
        {"name": "wire", "kind": "mask", "color": "#00aaff", "hotkey": "w"},
        {"name": "wire tip", "kind": "points", "point_names": ["tip"], "hotkey": "t"},
        {
            "name": "spatter",
            "kind": "instances",
            "hotkey": "x",
            "attributes": [{"name": "size", "type": "choice", "options": ["small", "large"]}],
        },
    ],
    "frame_tags": ["arc unstable"],
}
READER = r"""
import json, sys
from datumaro.components.dataset import Dataset
dataset = Dataset.import_from(sys.argv[1], "cvat")
labels = dataset.categories()[__import__("datumaro").AnnotationType.label]
items = []
for item in dataset:
    shapes = [
        {"type": a.type.name, "label": labels[a.label].name if a.label is not None else None,
         "attributes": {k: v for k, v in a.attributes.items()
                        if k not in ("occluded", "z_order", "outside", "keyframe", "track_id")},
         "points": [float(p) for p in getattr(a, "points", [])]}
        for a in item.annotations
    ]
    items.append({"id": item.id, "shapes": shapes})
print(json.dumps(items))
"""


def _png_b64(mask: np.ndarray) -> str:
    ok, data = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    assert ok
    return base64.b64encode(data.tobytes()).decode()


def _objects(pool: np.ndarray, seed: int) -> tuple[list[dict], dict]:
    """A wire above the pool, its tip, two spatters beside it: where a lab would draw them."""
    rng = np.random.default_rng(seed)
    height, width = pool.shape
    ys, xs = np.nonzero(pool)
    top, left = int(ys.min()), int(xs.min())
    wire = np.zeros_like(pool)
    tip = (left + int(rng.integers(20, 60)), max(top - 10, 1))
    wire[: tip[1], tip[0] - 6 : tip[0] + 6] = True
    spatter = []
    for dx in (-80, 80):
        blob = np.zeros_like(pool)
        cx = int(np.clip(xs.mean() + dx * 3, 10, width - 10))
        cv2.circle(blob.view(np.uint8), (cx, int(min(ys.max() + 30, height - 10))), 6, 1, -1)
        spatter.append(blob.astype(bool))
    objects = [{"class": "wire", "mask_png": _png_b64(wire)}]
    objects.append({"class": "wire tip", "points": {"tip": [float(tip[0]), float(tip[1])]}})
    objects += [
        {"class": "spatter", "mask_png": _png_b64(m), "attributes": {"size": size}}
        for m, size in zip(spatter, ["small", "large"], strict=True)
    ]
    return objects, {"tip": tip}


def _label_and_export(url: str, token: str) -> tuple[bytes, list[str], Counter, dict]:
    headers = {"Authorization": f"Bearer {token}"}
    client = httpx.Client(base_url=f"{url}/api/v1", headers=headers, timeout=120)
    client.put("/label-config", json=CONFIG).raise_for_status()
    labelled = sorted((SHARED_DATA / "waam" / "labels").glob("*.png"))
    frames = SHARED_DATA / "waam" / "frames"
    files = [("files", (p.name, (frames / p.name).read_bytes(), "image/png")) for p in labelled]
    stored = client.post("/frames", files=files).json()["stored"]
    ids = {f["original_name"]: f["id"] for f in stored}
    sent: Counter = Counter()
    tips: dict[str, tuple[float, ...]] = {}
    for number, path in enumerate(labelled):
        pool = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127
        objects, placed = _objects(pool, number)
        tips[path.stem] = tuple(float(v) for v in placed["tip"])
        body = {
            "status": "corrected",
            "base_revision": 0,
            "mask_png": _png_b64(pool),
            "objects": objects,
            "tags": ["arc unstable"] if number % 3 == 0 else [],
        }
        client.put(f"/frames/{ids[path.name]}/label", json=body).raise_for_status()
        sent.update(["pool", "pool keypoints"] + [o["class"] for o in objects])
        sent.update(["tag arc unstable"] * (number % 3 == 0))
        sent.update(["attribute size"] * 2)
    archive = client.get("/export", params={"format": "cvat"}).content
    return archive, [p.name for p in labelled], sent, tips


def _read_with_datumaro(python: str, archive: bytes) -> list[dict]:
    with tempfile.TemporaryDirectory() as folder:
        zipfile.ZipFile(io.BytesIO(archive)).extractall(folder)
        out = subprocess.run(
            [python, "-c", READER, folder], capture_output=True, text=True, check=True
        )
    return json.loads(out.stdout.strip().splitlines()[-1])


def _read_back(items: list[dict]) -> Counter:
    got: Counter = Counter()
    for item in items:
        for shape in item["shapes"]:
            if shape["type"] == "label":
                got[f"tag {shape['label']}"] += 1
                continue
            name = {"weld_pool": "pool"}.get(shape["label"], shape["label"])
            if name == "pool" and shape["type"] == "points":
                name = "pool keypoints"  # Algorithm 1's, which the export adds
            got[name] += 1
            got.update(["attribute size"] * ("size" in shape["attributes"]))
    return got


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datumaro-python", required=True)
    args = parser.parse_args()
    with local_server() as (url, token):
        archive, names, sent, tips = _label_and_export(url, token)
    items = _read_with_datumaro(args.datumaro_python, archive)
    frames = {Path(name).stem for name in names}  # CVAT's frame mapping: names without extension
    matched = sum(Path(item["id"]).name in frames for item in items)
    got = _read_back(items)
    # Datumaro reads one mask per connected run of CVAT's RLE, so a class's shape count is a
    # floor: each exported shape must come back at least once.
    read_tips = {
        Path(item["id"]).name: tuple(shape["points"])
        for item in items
        for shape in item["shapes"]
        if shape["label"] == "wire tip"
    }
    same = sum(read_tips.get(stem) == tip for stem, tip in tips.items())
    rows = [f"| images matched to the task's frames by name | {len(names)} | {matched} |"]
    rows.append(f"| wire tips at the place sent, (x, y) | {len(tips)} | {same} |")
    rows += [f"| {key} | {sent[key]} | {got[key]} |" for key in sorted(sent)]
    header = ["| CVAT acceptance | sent | read back by Datumaro |", "|---|---:|---:|"]
    print("\n".join([*header, *rows]))
    if matched != len(names) or same != len(tips) or any(got[key] < sent[key] for key in sent):
        sys.exit("CVAT would not take every frame's annotations (see the table).")


if __name__ == "__main__":
    with recorded(__file__):
        main()
