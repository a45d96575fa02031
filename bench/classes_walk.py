"""Issue 59's flow, walked in a real browser as a lab would, on ten real labelled frames.

Against a throw-away ``weldpool serve`` (SQLite, embedded worker, the tiny random-weight
teacher of the browser tests), Chromium driven by Playwright:

1. an admin adds ``wire`` (mask), ``wire tip`` (points, one point ``tip``), ``spatter``
   (instances) and the frame tag ``arc unstable`` on the Classes page, by typing and clicking;
2. uploads ten of the hand-labelled WAAM frames (``data/waam/labels/``) on the home page;
3. labels each on the review page with its tools: the pool as a polygon along the hand-drawn
   outline (the random teacher proposes nothing worth accepting), the wire as a polygon from
   the pool's notch (where the wire's droplet sits) to the frame's right edge, the tip as a
   point in the notch, two spatters as instances by brush, the tag on every third frame; saves;
4. trains from the models page with a few rounds (the form's **Rounds**), waits for the job
   and shows the version's per-class table;
5. reads every label and the version back through the API: objects, point positions and the
   pool against the hand-drawn mask, and the figures of every learned class.

Screenshots at 1280×800 and 1920×1080 go to ``--shots`` (default /tmp/shots/classes_walk).

``PYTHONPATH=. .venv/bin/python bench/classes_walk.py [--rounds 40]``
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
from common import REPO, SHARED_DATA, local_server
from results import recorded

PASSWORD = "weld-pool-2024"
SIZES = ((1280, 800), (1920, 1080))
TAG = "arc unstable"
CLASSES = [  # name, kind, hotkey, point names: typed into the Classes page
    ("wire", "mask", "w", ""),
    ("wire tip", "points", "t", "tip"),
    ("spatter", "instances", "x", ""),
]
SPATTER_BRUSH = 16  # px: a spatter is one brush dab


# --- where a lab draws each class on a real frame ---------------------------------------------


def _outline(stem: str, first_gap: float) -> list[tuple[float, float]]:
    """The hand-drawn pool outline, simplified to the corners a person would click (1.5 px),
    without corners near the first after the third (a click there closes the polygon)."""
    points = json.loads((SHARED_DATA / "waam" / "labels" / f"{stem}.json").read_text())["polygon"]
    curve = np.array(points, dtype=np.float32).reshape(-1, 1, 2)
    corners = [tuple(map(float, p[0])) for p in cv2.approxPolyDP(curve, 1.5, True)]
    first = np.array(corners[0])
    return corners[:3] + [c for c in corners[3:] if np.hypot(*(np.array(c) - first)) > first_gap]


def _plan(stem: str) -> dict[str, Any]:
    """The tip in the pool's notch on its right (the deepest concavity: the wire's droplet),
    the wire from there up to the frame's right edge, two spatters above the pool."""
    pool = cv2.imread(str(SHARED_DATA / "waam" / "labels" / f"{stem}.png"), cv2.IMREAD_GRAYSCALE)
    width = pool.shape[1]
    contours, _ = cv2.findContours((pool > 127).astype(np.uint8), 0, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=cv2.contourArea)
    defects = cv2.convexityDefects(contour, cv2.convexHull(contour, returnPoints=False))
    centre_x = float(contour[:, 0, 0].mean())
    right = [d for d in defects.reshape(-1, 4) if contour[d[2], 0, 0] > centre_x]
    far = max(right, key=lambda d: d[3])[2]
    tip = (float(contour[far, 0, 0]), float(contour[far, 0, 1]))
    end_y = max(14.0, tip[1] - 0.35 * (width - 1 - tip[0]))
    wire = [
        (tip[0] + 4, tip[1] - 10),
        (width - 1.0, end_y - 12),
        (width - 1.0, end_y + 12),
        (tip[0] + 4, tip[1] + 10),
    ]
    top = int(np.nonzero(pool)[0].min())
    spatter = [(centre_x - 220, max(20.0, top - 45.0)), (centre_x + 60, max(20.0, top - 70.0))]
    return {"pool": _outline(stem, 24), "wire": wire, "tip": tip, "spatter": spatter}


# --- the browser --------------------------------------------------------------------------------


def _shoot(page: Any, shots: Path, name: str) -> None:
    for width, height in SIZES:
        page.set_viewport_size({"width": width, "height": height})
        page.wait_for_timeout(300)
        page.screenshot(path=str(shots / f"{name}-{width}.png"))


def _login(page: Any, url: str, user: str) -> None:
    page.goto(f"{url}/login")
    page.fill("input[name=username]", user)
    page.fill("input[name=password]", PASSWORD)
    page.click("[data-testid=login-submit]")
    page.wait_for_url(f"{url}/")


def _define_classes(page: Any, url: str, shots: Path) -> None:
    page.click("[data-testid=nav-label-config]")
    page.wait_for_url(f"{url}/label-config")
    page.wait_for_selector("body[data-ready]")
    for name, kind, hotkey, points in CLASSES:
        page.click("[data-testid=add-class]")
        row = page.locator("[data-testid=class-row]").last
        row.locator("[data-testid=class-name]").fill(name)
        row.locator("[data-testid=class-kind]").select_option(kind)
        row.locator("[data-testid=class-hotkey]").fill(hotkey)
        if points:
            row.locator("[data-testid=class-points]").fill(points)
    page.fill("[data-testid=frame-tags]", TAG)
    page.click("[data-testid=save-config]")
    page.wait_for_selector("[data-testid=config-version]:has-text('Version 1')")
    _shoot(page, shots, "classes-page")


def _upload(page: Any, url: str, paths: list[Path]) -> dict[str, int]:
    """The frames through the home page's file input; their ids as the page reports them."""
    page.goto(f"{url}/")
    page.wait_for_selector("body[data-ready]")
    page.set_input_files("[data-testid=upload-input]", [str(p) for p in paths])
    items = page.locator("[data-testid=upload-item][data-state=ok]")
    deadline = time.monotonic() + 300
    while items.count() < len(paths):
        if time.monotonic() > deadline:
            raise RuntimeError(page.locator("[data-testid=upload-list]").inner_text())
        page.wait_for_timeout(200)
    ids = {}
    for item in items.all():
        text = item.inner_text()
        ids[item.get_attribute("data-name")] = int(text.split("frame #", 1)[1].split()[0])
    return ids


def _click(page: Any, x: float, y: float) -> None:
    from tests.pages import to_page

    page.mouse.click(*to_page(page, x, y))


def _polygon(page: Any, corners: list[tuple[float, float]], layer: str) -> None:
    """Corners clicked with the polygon tool, closed on the first; waits for the fill."""
    from tests.pages import wait_for_js

    for corner in [*corners, corners[0]]:
        _click(page, *corner)
    _wait_settled(page)
    wait_for_js(
        page,
        "(layer) => { const c = document.querySelector('[data-testid=frame-canvas]');"
        " if (c.dataset.pending !== '0') return false;"
        " if (layer === 'pool') return Number(c.dataset.maskArea) > 0;"
        " const o = JSON.parse(c.dataset.objects).find((o) => o.name === layer);"
        " return o && o.area > 0; }",
        arg=layer,
        timeout=60_000,
    )


def _wait_settled(page: Any) -> None:
    from tests.pages import wait_for_js

    wait_for_js(
        page,
        "() => document.querySelector('[data-testid=frame-canvas]').dataset.pending === '0'",
        timeout=60_000,
    )


def _label(page: Any, url: str, frame_id: int, plan: dict[str, Any], tagged: bool) -> float:
    """One frame labelled with the review page's tools and saved; seconds it took."""
    from tests.pages import open_review

    start = time.perf_counter()
    page.goto(f"{url}/frames/{frame_id}")
    open_review(page)
    _wait_settled(page)
    page.keyboard.press("7")  # the polygon tool, on the pool (the layer a page opens on)
    _polygon(page, plan["pool"], "pool")
    page.keyboard.press("w")
    _polygon(page, plan["wire"], "wire")
    page.keyboard.press("t")
    _click(page, *plan["tip"])
    page.keyboard.press("x")
    page.keyboard.press("4")  # the brush
    page.locator("[data-testid=brush-size]").fill(str(SPATTER_BRUSH))
    _click(page, *plan["spatter"][0])
    page.click("[data-testid=add-instance][data-class=spatter]")
    _click(page, *plan["spatter"][1])
    if tagged:
        page.click(f"[data-testid=frame-tag][data-tag='{TAG}']")
    page.uncheck("#advance")
    _wait_settled(page)
    page.click("[data-testid=save]")
    answer = page.locator("[data-testid=toast-ok], [data-testid=toast-error]").last
    answer.wait_for(timeout=60_000)
    if "Saved as corrected" not in answer.inner_text():
        raise RuntimeError(f"frame {frame_id} was not saved: {answer.inner_text()}")
    return time.perf_counter() - start


def _train(page: Any, url: str, rounds: int, shots: Path, http: httpx.Client) -> dict[str, Any]:
    """Train from the models page; the new version once its card shows the classes' table."""
    page.goto(f"{url}/models")
    page.wait_for_selector("body[data-ready]")
    page.fill("[data-testid=train-rounds]", str(rounds))
    page.click("[data-testid=train-button]")
    page.locator("[data-testid=train-state]", has_text="Training job").wait_for(timeout=60_000)
    deadline = time.monotonic() + 3600
    while True:
        jobs = http.get("/jobs", params={"kind": "train_student", "limit": 1}).json()["items"]
        job = jobs[0] if jobs else {}
        if job.get("status") in ("succeeded", "failed", "cancelled"):
            break
        if time.monotonic() > deadline:
            raise RuntimeError(f"training still {job.get('status')} after an hour")
        page.wait_for_timeout(2000)
    if job["status"] != "succeeded":
        raise RuntimeError(f"training job {job['id']} {job['status']}: {job.get('error')}")
    page.locator("[data-testid=model-classes]").first.wait_for(timeout=60_000)
    page.locator("[data-testid=model-classes]").first.scroll_into_view_if_needed()
    _shoot(page, shots, "models-classes")
    return dict(job)


# --- reading it back ----------------------------------------------------------------------------


def _mask(png_b64: str) -> np.ndarray:
    data = np.frombuffer(base64.b64decode(png_b64), np.uint8)
    return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) > 0


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def _read_back(
    http: httpx.Client, frame_id: int, stem: str, plan: dict, tagged: bool, back: Counter
) -> list[str]:
    """A frame's row of the table: what was drawn against what the label holds (``back``
    counts the objects and tags)."""
    from weldpool_core.outline import rle_mask

    label = http.get(f"/frames/{frame_id}/label").json()
    truth = cv2.imread(str(SHARED_DATA / "waam" / "labels" / f"{stem}.png"), 0) > 127
    by_class: dict[str, list[dict]] = {}
    for obj in label["objects"]:
        by_class.setdefault(obj["class"], []).append(obj)
    drawn_wire = np.zeros_like(truth, np.uint8)
    cv2.fillPoly(drawn_wire, [np.round(np.array(plan["wire"])).astype(np.int32)], 1)
    wires = by_class.get("wire", [])
    wire_iou = _iou(rle_mask(wires[0]["rle"]).astype(bool), drawn_wire > 0) if wires else 0.0
    tips = [o["points"]["tip"] for o in by_class.get("wire tip", [])]
    tip_error = float(np.hypot(*(np.array(tips[0]) - plan["tip"]))) if tips else float("inf")
    spatters = by_class.get("spatter", [])
    back.update({"wire": len(wires), "wire tip": len(tips), "spatter": len(spatters)})
    back.update([TAG] * (TAG in label["tags"]))
    spatter_error = max(
        (
            min(
                np.hypot(o["bbox"][0] + o["bbox"][2] / 2 - x, o["bbox"][1] + o["bbox"][3] / 2 - y)
                for o in spatters
            )
            for x, y in plan["spatter"]
        ),
        default=float("inf"),
    )
    return [
        stem,
        f"{_iou(_mask(label['mask_png']), truth):.3f}",
        f"1 / {len(wires)}",
        f"{wire_iou:.3f}",
        f"({plan['tip'][0]:.0f}, {plan['tip'][1]:.0f}) / "
        + (f"({tips[0][0]:.0f}, {tips[0][1]:.0f})" if tips else "–"),
        f"{tip_error:.1f}",
        f"2 / {len(spatters)}",
        f"{spatter_error:.1f}",
        f"{'yes' if tagged else 'no'} / {'yes' if TAG in label['tags'] else 'no'}",
        label["status"],
    ]


def _figure(row: dict | None) -> str:
    if not row or not row.get("frames"):
        return "–"
    if row["kind"] == "points":
        missed = f", {row['missed']} not found" if row.get("missed") else ""
        return f"{row['distance_px']:.1f} px on {row['frames']}{missed}"
    return f"IoU {row['IoU']:.3f} on {row['frames']}"


# --- the walk -----------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=40, help="the models page's Rounds")
    parser.add_argument("--shots", type=Path, default=Path("/tmp/shots/classes_walk"))
    args = parser.parse_args()
    labelled = sorted((SHARED_DATA / "waam" / "labels").glob("*.png"))
    if not labelled:
        sys.exit(f"The real frames are not here ({SHARED_DATA / 'waam'}).")
    chosen = [p for p in labelled if "f0300" not in p.stem][:10]
    frames = [SHARED_DATA / "waam" / "frames" / p.name for p in chosen]
    args.shots.mkdir(parents=True, exist_ok=True)

    from playwright.sync_api import sync_playwright

    sys.path.insert(0, str(REPO))
    from tests.models import save_tiny_teacher
    from tests.pages import accept_dialogs
    from tests.web.server import launch_chromium

    with tempfile.TemporaryDirectory() as root:
        teacher = save_tiny_teacher(Path(root) / "teacher")
        env = {
            "HF_HUB_OFFLINE": "1",
            "WELDPOOL_HOME": str(Path(root) / "home"),
            "WELDPOOL_SAM2": str(teacher["sam2"]),
            "WELDPOOL_DINO": str(teacher["dino"]),
            "WELDPOOL_DINO_INPUT_SIZE": str(teacher["dino_input_size"]),
            "WELDPOOL_DEVICE": "cpu",
            "WELDPOOL_RETRAIN_EVERY": "0",
        }
        with local_server(env) as (url, token), sync_playwright() as playwright:
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "app",
                    "user",
                    "add",
                    "ada",
                    "--role=admin",
                    "--password-stdin",
                ],
                input=PASSWORD,
                text=True,
                env=dict(os.environ, **env),
                cwd=REPO,
                check=True,
                capture_output=True,
            )
            http = httpx.Client(
                base_url=f"{url}/api/v1", headers={"Authorization": f"Bearer {token}"}, timeout=60
            )
            browser = launch_chromium(playwright)
            page = browser.new_page(viewport={"width": 1920, "height": 1080})
            accept_dialogs(page)
            _login(page, url, "ada")
            start = time.perf_counter()
            _define_classes(page, url, args.shots)
            ids = _upload(page, url, frames)
            page.set_viewport_size({"width": 1920, "height": 1080})
            plans, seconds = {}, []
            for number, path in enumerate(chosen):
                plans[path.stem] = _plan(path.stem)
                seconds.append(_label(page, url, ids[path.name], plans[path.stem], number % 3 == 0))
                if number == 0:
                    page.click("[data-testid=layer-row][data-class=spatter] >> nth=1")
                    _shoot(page, args.shots, "review-labelled")
                    page.set_viewport_size({"width": 1920, "height": 1080})
            labelling = time.perf_counter() - start
            back: Counter = Counter()
            rows = [
                _read_back(http, ids[p.name], p.stem, plans[p.stem], n % 3 == 0, back)
                for n, p in enumerate(chosen)
            ]
            page.set_viewport_size({"width": 1280, "height": 800})
            job = _train(page, url, args.rounds, args.shots, http)
            models = http.get("/models").json()
            browser.close()
    version = models[0]
    learned = version["config"]["student"].get("classes") or []
    gate, validation = version.get("gate") or {}, version.get("metrics") or {}
    columns = [
        "frame",
        "pool IoU vs hand mask",
        "wire sent / back",
        "wire IoU vs drawn",
        "tip sent / back (x, y)",
        "tip error px",
        "spatter sent / back",
        "spatter centre error px",
        "tag sent / back",
        "status",
    ]
    print("| " + " | ".join(columns) + " |")
    print("|---|" + "---:|" * (len(columns) - 1))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()
    print("| learned class | kind | points | gate (held-out frames) | training validation |")
    print("|---|---|---|---:|---:|")
    print(
        f"| pool | mask | – | mIoU {gate.get('candidate', {}).get('mIoU', float('nan')):.3f} |"
        f" mIoU {validation.get('mIoU', float('nan')):.3f} |"
    )
    for c in learned:
        name = c["name"]
        print(
            f"| {name} | {c['kind']} | {', '.join(c.get('points') or []) or '–'} |"
            f" {_figure((gate.get('classes') or {}).get(name))} |"
            f" {_figure((validation.get('classes') or {}).get(name))} |"
        )
    print()
    print("| walk | value |")
    print("|---|---:|")
    print(f"| frames labelled in the browser | {len(rows)} |")
    print(f"| labelling, median s a frame | {float(np.median(seconds)):.1f} |")
    print(f"| classes page to last save, s | {labelling:.0f} |")
    print(f"| training rounds (models page) | {args.rounds} |")
    print(f"| training job, s | {_job_seconds(job):.0f} |")
    print(f"| screenshots | {len(list(args.shots.glob('*.png')))} in {args.shots} |")
    n = len(rows)
    sent = Counter({"wire": n, "wire tip": n, "spatter": 2 * n, TAG: (n + 2) // 3})
    names = {c["name"] for c in learned}
    missing = sorted({name for name, *_ in CLASSES} - names)
    no_figure = sorted(name for name in names if not (gate.get("classes") or {}).get(name))
    if back != sent or missing or no_figure:
        sys.exit(
            f"Not every class came back: {dict(back)} of {dict(sent)}; not learned {missing}; "
            f"without a gate figure {no_figure}."
        )


def _job_seconds(job: dict[str, Any]) -> float:
    from datetime import datetime

    started, finished = job.get("started_at"), job.get("finished_at")
    if not started or not finished:
        return float("nan")
    return (datetime.fromisoformat(finished) - datetime.fromisoformat(started)).total_seconds()


if __name__ == "__main__":
    with recorded(__file__):
        main()
