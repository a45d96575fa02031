"""Benchmark label import: 1,000 labelled 1280×800 frames from one zip, COCO RLE and polygons.

Run: ``PYTHONPATH=. .venv/bin/python bench/label_import.py [--frames 1000] [--runs 3]``

The zip holds the real WAAM frames (cycled; each copy differs in one pixel, so every frame is
new content) and one pool mask per frame (an ellipse cut off at the wire, as in
``bench/export.py``), written as compressed RLE or as COCO polygons (``region_outlines``). Each
run imports it into a fresh home and SQLite database through ``app.imports.service`` (what the
job runs: read, store the frames, rasterise, store masks, write labels and history), timed from
opening the zip to the last commit. The reference is the same frames uploaded without labels
(``ingest_frames`` in batches of 64, the upload path): the ratio says what the labels add.
Median of ``--runs``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import cv2
import numpy as np
from common import SHARED_DATA
from results import Table, record

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role, User
from app.core.schema import migrate
from app.core.security import hash_password
from app.frames.ingest import IncomingFile, ingest_frames
from app.frames.sequences import create_sequence
from app.imports.schemas import ImportOptions
from app.imports.service import import_labels
from app.proposals import policy
from app.storage import LocalStorage, open_storage
from weldpool_core.annotations import open_source
from weldpool_core.outline import coco_mask, region_outlines

REPO = Path(__file__).resolve().parents[1]
FRAMES = SHARED_DATA / "waam" / "frames"
GOALS = {"rle": 200.0, "polygons": 150.0, "rle, labels only": 200.0}


def _mask(rng: np.random.Generator) -> np.ndarray:
    mask = np.zeros((800, 1280), np.uint8)
    centre = (int(rng.integers(500, 800)), int(rng.integers(350, 450)))
    axes = (int(rng.integers(250, 400)), int(rng.integers(100, 180)))
    cv2.ellipse(mask, centre, axes, float(rng.uniform(-10, 10)), 0, 360, 1, -1)
    cv2.rectangle(mask, (centre[0] + axes[0] - 60, centre[1] - 20), (1280, centre[1]), 0, -1)
    return mask > 0


def build(folder: Path, count: int) -> tuple[Path, Path, list[bytes]]:
    """The two zips (RLE, polygons) and the frames' bytes, cached in ``folder``."""
    rle_zip, polygon_zip = folder / f"coco-rle-{count}.zip", folder / f"coco-poly-{count}.zip"
    sources = sorted(FRAMES.glob("*.png"))
    if not sources:
        sys.exit(f"no frames in {FRAMES}")
    decoded = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sources]
    images: list[bytes] = []
    for index in range(count):
        pixels = decoded[index % len(decoded)].copy()
        pixels.reshape(-1)[:2] = (index % 256, index // 256)  # new content, same look
        images.append(cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes())
    if rle_zip.exists() and polygon_zip.exists():
        return rle_zip, polygon_zip, images
    rng = np.random.default_rng(0)
    masks = [_mask(rng) for _ in range(count)]
    for target, polygons in ((rle_zip, False), (polygon_zip, True)):
        records, annotations = [], []
        for index, mask in enumerate(masks):
            records.append(
                {"id": index, "file_name": f"f{index:05d}.png", "width": 1280, "height": 800}
            )
            if polygons:
                segmentation = [
                    [v + 0.5 for point in outline for v in point]
                    for outline in region_outlines(mask)
                ]
            else:
                segmentation = coco_mask(mask).rle
            annotations.append(
                {"id": index, "image_id": index, "category_id": 1, "segmentation": segmentation}
            )
        document = {
            "images": records,
            "annotations": annotations,
            "categories": [{"id": 1, "name": "weld_pool"}],
        }
        with zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as archive:
            archive.writestr("annotations.json", json.dumps(document))
            for index, data in enumerate(images):
                archive.writestr(f"images/f{index:05d}.png", data)
    return rle_zip, polygon_zip, images


def _fresh(root: Path) -> tuple[Settings, object, User]:
    home = Path(tempfile.mkdtemp(dir=root))
    settings = Settings(_env_file=None, home=home)  # type: ignore[call-arg]
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    factory = create_session_factory(engine)
    policy.watch(factory, open_storage(settings))  # as the service's: a commit measures the policy
    with factory() as session:
        user = User(username="bench", password_hash=hash_password("bench-bench"), role=Role.admin)
        session.add(user)
        session.commit()
        session.refresh(user)
        session.expunge(user)
    return settings, factory, user


def time_import(root: Path, archive: Path) -> tuple[float, int]:
    settings, factory, user = _fresh(root)
    start = time.perf_counter()
    source = open_source(archive)
    with factory() as session:  # type: ignore[operator]
        user = session.merge(user)
        report = import_labels(
            session, LocalStorage(settings.home), source, ImportOptions("coco"), user
        )
    source.close()
    elapsed = time.perf_counter() - start
    assert not report.refused, report.refused[:3]
    return elapsed, report.labels


def time_labels_only(root: Path, archive: Path, images: list[bytes]) -> float:
    """The labels of frames already stored (uploaded first, by name): the annotation file
    alone, imported into their run."""
    settings, factory, user = _fresh(root)
    run_id = _ingested(settings, factory, user, images)
    folder = Path(tempfile.mkdtemp(dir=root))
    with zipfile.ZipFile(archive) as bundle:
        (folder / "annotations.json").write_bytes(bundle.read("annotations.json"))
    start = time.perf_counter()
    source = open_source(folder / "annotations.json")
    with factory() as session:  # type: ignore[operator]
        user = session.merge(user)
        options = ImportOptions("coco", sequence_id=run_id)
        report = import_labels(session, LocalStorage(settings.home), source, options, user)
    source.close()
    elapsed = time.perf_counter() - start
    assert not report.refused and report.labels == len(images), report.refused[:3]
    return elapsed


def time_ingest(root: Path, images: list[bytes]) -> float:
    settings, factory, user = _fresh(root)
    start = time.perf_counter()
    _ingested(settings, factory, user, images)
    return time.perf_counter() - start


def _ingested(settings: Settings, factory: object, user: User, images: list[bytes]) -> int:
    """``images`` uploaded into a new run in batches of 64 (the upload path), named as the
    zips name them; the run's id."""
    with factory() as session:  # type: ignore[operator]
        user = session.merge(user)
        run = create_sequence(session, {"name": "ingest"}, user)
        for first in range(0, len(images), 64):
            files = [
                IncomingFile(f"f{i:05d}.png", images[i])
                for i in range(first, min(first + 64, len(images)))
            ]
            ingest_frames(
                session,
                LocalStorage(settings.home),
                files,
                sequence_id=run.id,
                user=user,
                max_pixels=25_000_000,
            )
        return int(run.id)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "weldpool-bench-import"
    )
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    rle_zip, polygon_zip, images = build(args.cache, args.frames)
    with tempfile.TemporaryDirectory(dir=args.cache) as scratch:
        root = Path(scratch)
        ingest = statistics.median(time_ingest(root, images) for _ in range(args.runs))
        rows = []
        for name, archive in (("rle", rle_zip), ("polygons", polygon_zip)):
            times = []
            for _ in range(args.runs):
                elapsed, labels = time_import(root, archive)
                assert labels == args.frames
                times.append(elapsed)
            rows.append((name, statistics.median(times)))
        labels_only = [time_labels_only(root, rle_zip, images) for _ in range(args.runs)]
        rows.append(("rle, labels only", statistics.median(labels_only)))
    n = args.frames
    print(f"{n} labelled 1280×800 frames from one zip, median of {args.runs} runs, SQLite")
    print(f"{'import':<22}{'s':>8}{'frames/s':>10}{'goal':>8}{'× ingest':>10}")
    print(f"{'frames only (ingest)':<22}{ingest:8.2f}{n / ingest:10.0f}{'':>8}{1.0:10.2f}")
    table = Table(
        "import",
        ["import", "s", "frames/s", "goal", "× ingest"],
        [["frames only (ingest)", f"{ingest:.2f}", f"{n / ingest:.0f}", "", "1.00"]],
    )
    for name, seconds in rows:
        print(
            f"{'COCO ' + name:<24}{seconds:8.2f}{n / seconds:10.0f}{GOALS[name]:8.0f}"
            f"{seconds / ingest:10.2f}"
        )
        table.rows.append(
            [
                *(f"COCO {name}", f"{seconds:.2f}", f"{n / seconds:.0f}"),
                *(f"{GOALS[name]:.0f}", f"{seconds / ingest:.2f}"),
            ]
        )
    command = shlex.join(
        ["PYTHONPATH=.", ".venv/bin/python", "bench/label_import.py", *sys.argv[1:]]
    )
    print(f"written to {record('bench/label_import.py', [table], command)}")


if __name__ == "__main__":
    main()
