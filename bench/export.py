"""Benchmark the streamed export of reviewed labels against the zip-copy floor.

Run: ``PYTHONPATH=. .venv/bin/python bench/export.py [--labels 400] [--runs 3] [--formats coco,cvat]
[--s3 URL]``

It stores N labelled frames as review leaves them (the real WAAM frames, cycled, as the images;
a different hand-drawn-like pool mask per label, as a 0/255 PNG), then times ``GET
/api/v1/export`` for each format in process (the whole request path, streamed): the time to the
first byte, the time to the last, and the process's peak RSS and temporary files. The floor is
the zip-copy of the same image and mask files into an in-memory zip (what any exporter must at
least do); the ratio is the export's total over it, and the writer's (the zip written in
process, without the request around it) over it: the floor has no HTTP path. Median of
``--runs``. Labels carry the RLE, area, box and outlines that saving stores with them; ``yolo
unstored`` is the YOLO export after the outlines are dropped (labels saved before revision 0011:
every mask decoded from its RLE and traced during the export), ``coco unstored`` the COCO export
after the RLE, area and box are dropped too (labels saved before revision 0008: every mask PNG
decoded and encoded). With ``--s3 ENDPOINT`` the same labels are stored in an object store (a
fresh bucket) and exported by a process whose cache is cold (the home's copies removed before
each run), beside the home folder's export (goal ≤ 1.5×).
"""

from __future__ import annotations

import argparse
import io
import resource
import shutil
import statistics
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import cv2
import numpy as np
import sqlalchemy as sa
from common import SHARED_DATA
from fastapi.testclient import TestClient
from results import recorded

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Frame, Label, LabelStatus, Role, Sequence, Split, User
from app.core.schema import migrate
from app.core.security import hash_password, issue_token
from app.main import create_app
from app.review.export import export_rows, stream_export
from app.storage import LocalStorage, Storage, open_storage
from weldpool_core.io import encode_png
from weldpool_core.outline import coco_mask, region_outlines

REPO = Path(__file__).resolve().parents[1]
FRAMES = SHARED_DATA / "waam" / "frames"


def fill(settings: Settings, count: int) -> tuple[str, list[str]]:
    """``count`` labelled frames; returns an admin token and the stored files (the floor's)."""
    storage = open_storage(settings)
    sources = sorted(FRAMES.glob("*.png"))
    if not sources:
        sys.exit(f"no frames in {FRAMES}")
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    files: list[str] = []
    with create_session_factory(engine)() as session:
        user = User(username="bench", password_hash=hash_password("bench-bench"), role=Role.admin)
        run = Sequence(name="export run", wire_feed_m_min=6.0, voltage_v=21.5)
        session.add_all([user, run])
        session.flush()
        images = []
        for source in sources:
            data = source.read_bytes()
            images.append((storage.put(data, f"{abs(hash(source.name)):064d}", ".png").path, data))
        rng = np.random.default_rng(0)
        for index in range(count):
            path, data = images[index % len(images)]
            mask = np.zeros((800, 1280), np.uint8)
            centre = (int(rng.integers(500, 800)), int(rng.integers(350, 450)))
            axes = (int(rng.integers(250, 400)), int(rng.integers(100, 180)))
            cv2.ellipse(mask, centre, axes, float(rng.uniform(-10, 10)), 0, 360, 255, -1)
            cv2.rectangle(
                mask, (centre[0] + axes[0] - 60, centre[1] - 20), (1280, centre[1]), 0, -1
            )
            png = encode_png(mask)
            coco = coco_mask(mask > 0)  # what saving a label stores with it
            outlines = region_outlines(mask > 0)
            # where the service keeps label masks (app.proposals.files): a store's shared area
            stored = storage.put(png, f"{index:064x}", ".png", area="artefacts")
            frame = Frame(
                sequence_id=run.id,
                sha256=f"{index:064x}",
                path=path,
                original_name=f"f{index:05d}.png",
                media_type="image/png",
                size_bytes=len(data),
                width=1280,
                height=800,
                channels=1,
                frame_index=index,
                split=Split.train,
            )
            session.add(frame)
            session.flush()
            keypoints = [[float(x), float(y)] for x, y in rng.uniform(100, 700, (4, 2))]
            session.add(
                Label(
                    frame_id=frame.id,
                    status=LabelStatus.accepted,
                    mask_path=stored.path,
                    keypoints=keypoints,
                    mask_rle=coco.rle,
                    mask_area=coco.area,
                    mask_bbox=coco.bbox,
                    mask_outlines=outlines,
                )
            )
            files += [path, stored.path]
        _, token = issue_token(session, user, "bench")
        session.commit()
    engine.dispose()
    return token, files


def forget(settings: Settings, **columns: None) -> None:
    """Drop stored values, as labels saved before the revision that stores them have none."""
    engine = create_db_engine(settings.resolved_database_url)
    with engine.begin() as connection:
        connection.execute(sa.update(Label).values(**columns))
    engine.dispose()


def floor_s(storage: Storage, files: list[str]) -> float:
    """Zip-copy of the export's files into memory (stored, like the export)."""
    start = time.perf_counter()
    with zipfile.ZipFile(io.BytesIO(), "w", zipfile.ZIP_STORED) as archive:
        for index, relative in enumerate(files):
            archive.write(storage.absolute(relative), f"{index}{Path(relative).suffix}")
    return time.perf_counter() - start


FORMATS = ("coco", "masks", "yolo", "cvat", "yolo unstored", "coco unstored")


def writer_s(settings: Settings, fmt: str) -> float:
    """The export's zip written in this process, without the request around it: what the
    service itself does (rows loaded, files read, entries written), beside the floor; the
    request's total adds the HTTP path (in process: the test client's thread hops)."""
    engine = create_db_engine(settings.resolved_database_url)
    try:
        with create_session_factory(engine)() as session:
            start = time.perf_counter()
            rows = export_rows(session, None, None)
            for _ in stream_export(open_storage(settings), fmt, rows):  # type: ignore[arg-type]
                pass
            return time.perf_counter() - start
    finally:
        engine.dispose()


def export_times(
    settings: Settings, token: str, formats: tuple[str, ...], runs: int, cold: bool = False
) -> dict[str, tuple[float, float, int, int, float]]:
    """(first byte s, total s, bytes, most temporary files, this process's CPU s) of each
    format's export, median of ``runs``; ``cold``: the home's cached copies of the store's
    files removed before each run (a process that has not read them yet). The CPU is the
    work competing with the writer for this process's GIL (not the service's processes')."""
    found = {}
    with TestClient(create_app(settings, embedded_worker=False)) as client:
        for fmt in formats:
            if fmt == "yolo unstored":  # labels saved before their outlines were (0011)
                forget(settings, mask_outlines=None)
            if fmt == "coco unstored":  # … and before their RLE was stored (0008)
                forget(settings, mask_rle=None, mask_area=None, mask_bbox=None)
            firsts, totals, cpus, size, leftovers = [], [], [], 0, 0
            for _ in range(runs):
                if cold:
                    for area in ("frames", "artefacts"):
                        shutil.rmtree(settings.home / area, ignore_errors=True)
                start, cpu = time.perf_counter(), time.process_time()
                first = None
                size = 0
                with client.stream(
                    "GET",
                    "/api/v1/export",
                    params={"format": fmt.split()[0]},
                    headers={"Authorization": f"Bearer {token}"},
                ) as response:
                    assert response.status_code == 200, response.read()
                    for chunk in response.iter_raw():
                        first = first or time.perf_counter()
                        size += len(chunk)
                        leftovers = max(leftovers, len(list((settings.home / "tmp").glob("*"))))
                totals.append(time.perf_counter() - start)
                cpus.append(time.process_time() - cpu)
                firsts.append((first or time.perf_counter()) - start)
            median = statistics.median
            found[fmt] = median(firsts), median(totals), size, leftovers, median(cpus)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--labels", type=int, default=400)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--formats",
        default=",".join(FORMATS),
        help=f"comma-separated, of {', '.join(FORMATS)} (default: all)",
    )
    parser.add_argument(
        "--s3",
        metavar="ENDPOINT",
        help="also export from an object store at ENDPOINT (moto: http://127.0.0.1:5000) "
        "in a process whose cache is cold, beside the home folder's export",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as home:
        settings = Settings(_env_file=None, home=Path(home))  # type: ignore[call-arg]
        token, files = fill(settings, args.labels)
        storage = LocalStorage(settings.home)
        floor = statistics.median(floor_s(storage, files) for _ in range(args.runs))
        formats = tuple(f.strip() for f in args.formats.split(","))
        if unknown := sorted(set(formats) - set(FORMATS)):
            sys.exit(f"unknown formats: {', '.join(unknown)}")
        writers = {  # first: the unstored formats' runs drop the stored values for good
            fmt: statistics.median(writer_s(settings, fmt) for _ in range(args.runs))
            for fmt in formats
            if " " not in fmt
        }
        local = export_times(settings, token, formats, args.runs)
    print(f"{args.labels} labels, SQLite; zip-copy floor {floor * 1000:.0f} ms\n")
    print(
        "| format | first byte ms | total ms | × floor | writer ms | writer × floor | MB | "
        "temporary files | CPU ms |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for fmt, (first, total, size, leftovers, cpu) in local.items():
        writer = writers.get(fmt)
        alone = "– | –" if writer is None else f"{writer * 1000:.0f} | {writer / floor:.2f}×"
        print(
            f"| {fmt} | {first * 1000:.0f} | {total * 1000:.0f} | {total / floor:.2f}× | "
            f"{alone} | {size / 1e6:.0f} | {leftovers} | {cpu * 1000:.0f} |",
            flush=True,
        )
    if args.s3:
        cold_exports(args, local, writers)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak RSS of this process: {peak:.0f} MB")


def cold_exports(
    args: argparse.Namespace,
    local: dict[str, tuple[float, float, int, int, float]],
    writers: dict[str, float],
) -> None:
    """The same exports from an object store, each from a cold cache, beside the local ones:
    the request, and the writer alone."""
    from storage import bucket  # bench/storage.py: a fresh bucket on the endpoint

    formats = tuple(f for f in ("coco", "masks", "cvat") if f in local)
    with tempfile.TemporaryDirectory() as home:
        settings = Settings(  # type: ignore[call-arg]
            _env_file=None,
            home=Path(home),
            storage_url=f"s3://{bucket(args.s3)}/bench",
            s3_endpoint_url=args.s3,
        )
        token, _ = fill(settings, args.labels)
        remote = export_times(settings, token, formats, args.runs, cold=True)
        alone = {
            fmt: statistics.median(cold_writer_s(settings, fmt) for _ in range(args.runs))
            for fmt in formats
        }
    print(f"\nthe object store at {args.s3}, cache cold before each export\n")
    print("| format | first byte ms | total ms | × local | writer ms | writer × local |")
    print("|---|---:|---:|---:|---:|---:|")
    for fmt in formats:
        first, total, *_ = remote[fmt]
        print(
            f"| {fmt} (cold) | {first * 1000:.0f} | {total * 1000:.0f} | "
            f"{total / local[fmt][1]:.2f}× | {alone[fmt] * 1000:.0f} | "
            f"{alone[fmt] / writers[fmt]:.2f}× |",
            flush=True,
        )


def cold_writer_s(settings: Settings, fmt: str) -> float:
    """``writer_s`` after the home's cached copies of the store's files are removed."""
    for area in ("frames", "artefacts"):
        shutil.rmtree(settings.home / area, ignore_errors=True)
    return writer_s(settings, fmt)


if __name__ == "__main__":
    with recorded(__file__):
        main()
