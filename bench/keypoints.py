"""How steady are Algorithm 1's keypoints on real pools? Ours against the paper's plain K-means.

Reads the 9 hand-drawn WAAM pool masks of ../shared/data/waam/labels (or $WELDPOOL_SHARED_DATA;
read, never copied) and prints, for Algorithm 1 as built (``heatmap_from_mask``: groups anchored
at the pool's corners) and for the paper's step 4 taken literally (OpenCV's K-means on the
high-curvature points, k-means++ seeds, the keypoint the contour point nearest each mean, the
order rule by angle):

- within a clip: how far keypoint j moves between the clip's three labelled frames (the camera
  moves with the torch, so the pool barely moves), mean and largest over keypoints and pairs;
- nudged: how far keypoint j moves when the outline is moved by a smooth random displacement of
  about 2, 4 or 8 px (3 seeds each), mean and largest;
- the time per 1280×800 mask (median of 5).

Keypoints are compared by their number (the order rule), as a controller or mED_k reads them;
a keypoint that changes places with another counts as the distance it jumped.

    PYTHONPATH=. .venv/bin/python bench/keypoints.py
"""

from __future__ import annotations

import itertools
import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from results import Table, record

from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.keypoints import order_by_angle
from weldpool_core.synth import nudge_outline

REPO = Path(__file__).resolve().parents[1]
Method = Callable[[NDArray[np.bool_]], NDArray[np.float64]]


def labels() -> Path:
    root = Path(os.environ.get("WELDPOOL_SHARED_DATA") or REPO.parent / "shared" / "data")
    return root / "waam" / "labels"


def ours(mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    return heatmap_from_mask(mask).keypoints


def plain_kmeans(mask: NDArray[np.bool_], k: int = 4) -> NDArray[np.float64]:
    """METHOD.md's steps 1–4 read literally: blur 9, |Δθ| > 0.5 over ±1 % of the outline,
    OpenCV K-means (k-means++, 5 attempts, fixed seed) on those points, nearest contour points."""
    smoothed = cv2.blur(mask.astype(np.float32), (9, 9))
    contours, _ = cv2.findContours(
        (smoothed >= 0.5).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    contour = max(contours, key=cv2.contourArea).reshape(-1, 2)
    gx = cv2.Sobel(smoothed, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smoothed, cv2.CV_32F, 0, 1, ksize=3)
    normal = np.arctan2(gy[contour[:, 1], contour[:, 0]], gx[contour[:, 1], contour[:, 0]])
    step = max(2, round(0.01 * len(contour)))
    turn = np.abs(np.mod(np.roll(normal, -step) - np.roll(normal, step) + math.pi, 2 * math.pi))
    bends = contour[np.abs(turn - math.pi) > 0.5].astype(np.float32)
    cv2.setRNGSeed(0)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1)
    _, _, centres = cv2.kmeans(bends, k, None, criteria, 5, cv2.KMEANS_PP_CENTERS)
    nearest = [contour[np.argmin(np.hypot(*(contour - c).T))] for c in centres]
    points = np.array(nearest, np.float64)
    moments = cv2.moments(contour)
    centre = (moments["m10"] / moments["m00"], moments["m01"] / moments["m00"])
    ordered: NDArray[np.float64] = points[order_by_angle(points, centre)]
    return ordered


def moves(a: NDArray[np.float64], b: NDArray[np.float64]) -> list[float]:
    return [float(d) for d in np.linalg.norm(a - b, axis=1)]


def main() -> None:
    folder = labels()
    if not folder.is_dir():
        raise SystemExit(f"no real labels at {folder} (set WELDPOOL_SHARED_DATA)")
    masks = {
        p.stem: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 127 for p in sorted(folder.glob("*.png"))
    }
    methods: dict[str, Method] = {
        f"ours (anchored groups, k={HeatmapParams().k})": ours,
        "paper's K-means (cv2.kmeans)": plain_kmeans,
    }
    table = Table(
        "Algorithm 1",
        [
            *("Algorithm 1", "within a clip: mean / largest px", "nudged 2 px", "nudged 4 px"),
            *("nudged 8 px", "ms per mask"),
        ],
        [],
    )
    print(table.markdown())
    for name, method in methods.items():
        points = {stem: method(mask) for stem, mask in masks.items()}
        clips: dict[str, list[str]] = {}
        for stem in points:
            clips.setdefault(stem.rsplit("_", 1)[0], []).append(stem)
        within = [
            d
            for stems in clips.values()
            for a, b in itertools.combinations(stems, 2)
            for d in moves(points[a], points[b])
        ]
        cells = [f"{statistics.mean(within):.1f} / {max(within):.1f}"]
        for amplitude in (2.0, 4.0, 8.0):
            shifts = [
                d
                for stem, mask in masks.items()
                for seed in range(3)
                for d in moves(method(nudge_outline(mask, seed, amplitude)), points[stem])
            ]
            cells.append(f"{statistics.mean(shifts):.1f} / {max(shifts):.1f}")
        mask = next(iter(masks.values()))
        times = []
        for _ in range(5):
            start = time.perf_counter()
            method(mask)
            times.append((time.perf_counter() - start) * 1000)
        cells.append(f"{statistics.median(times):.1f}")
        table.rows.append([name, *cells])
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    print(f"written to {record('bench/keypoints.py', [table])}")


if __name__ == "__main__":
    main()
