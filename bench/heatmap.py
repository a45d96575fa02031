"""Benchmark Algorithm 1: milliseconds per mask, against a straightforward implementation.

Run: ``.venv/bin/python bench/heatmap.py``. The masks are synthetic weld pools (``synth``) at
1280×800 (the WAAM camera) and 256×256; each time is the median of 20 calls. The straightforward
version (below, for this comparison only) follows the paper step by step on the whole image with
per-point Python loops and full-image Gaussians; it has no separation or completion step.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from results import Table, record

from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.synth import SynthParams, synth_frame

REPEATS = 20


def straightforward_heatmap(mask: NDArray[np.bool_], params: HeatmapParams) -> NDArray[Any]:
    """The paper's Algorithm 1 written plainly: whole-image filters, a loop per contour point."""
    smoothed = cv2.blur(mask.astype(np.float32), (params.blur_size, params.blur_size))
    binary = (smoothed >= 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=cv2.contourArea).reshape(-1, 2)
    gx = cv2.Sobel(smoothed, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smoothed, cv2.CV_32F, 0, 1, ksize=3)
    angles = []
    for x, y in contour:
        angles.append(math.atan2(float(gy[y, x]), float(gx[y, x])))
    step = max(2, round(params.turn_step * len(contour)))
    bends = []
    for i in range(len(contour)):
        change = angles[(i + step) % len(contour)] - angles[i - step]
        change = (change + math.pi) % (2 * math.pi) - math.pi
        if abs(change) > params.turn_threshold:
            bends.append([float(contour[i][0]), float(contour[i][1])])
    if len(bends) < params.k:
        bends = [[float(x), float(y)] for x, y in contour]
    cv2.setRNGSeed(0)
    _, labels, _ = cv2.kmeans(
        np.array(bends, np.float32),
        params.k,
        None,
        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-3),
        3,
        cv2.KMEANS_PP_CENTERS,
    )
    ys, xs = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]].astype(np.float32)
    heat = np.zeros(mask.shape, np.float32)
    for group in range(params.k):
        members = [bends[i] for i in range(len(bends)) if labels[i, 0] == group]
        mx = sum(p[0] for p in members) / len(members)
        my = sum(p[1] for p in members) / len(members)
        sxx = sum((p[0] - mx) ** 2 for p in members) / len(members) + params.covariance_floor
        syy = sum((p[1] - my) ** 2 for p in members) / len(members) + params.covariance_floor
        sxy = sum((p[0] - mx) * (p[1] - my) for p in members) / len(members)
        inverse = np.linalg.inv(np.array([[sxx, sxy], [sxy, syy]]))
        dx, dy = xs - mx, ys - my
        heat += np.exp(
            -0.5 * (inverse[0, 0] * dx * dx + 2 * inverse[0, 1] * dx * dy + inverse[1, 1] * dy * dy)
        )
    return np.dstack([heat * smoothed, mask.astype(np.float32)])


def median_ms(function: Callable[[], object]) -> float:
    function()  # warm-up
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        function()
        times.append((time.perf_counter() - start) * 1000)
    return statistics.median(times)


def main() -> None:
    params = HeatmapParams()
    print(
        f"Algorithm 1, median of {REPEATS} calls, {os.cpu_count()} CPU cores, "
        f"OpenCV threads {cv2.getNumThreads()}"
    )
    print(f"{'mask':>10} | {'heatmap_from_mask':>17} | {'straightforward':>15} | {'ratio':>6}")
    print(f"{'-' * 10}-+-{'-' * 17}-+-{'-' * 15}-+-{'-' * 6}")
    table = Table("mask", ["mask", "heatmap_from_mask ms", "straightforward ms", "ratio"], [])
    for width, height in ((1280, 800), (256, 256)):
        mask = synth_frame(0, SynthParams(width=width, height=height)).mask
        fast = median_ms(lambda mask=mask: heatmap_from_mask(mask, params))
        plain = median_ms(lambda mask=mask: straightforward_heatmap(mask, params))
        print(
            f"{width:>5}×{height:<4} | {fast:>14.2f} ms | {plain:>12.2f} ms | {plain / fast:>5.1f}×"
        )
        ratio = f"{plain / fast:.1f}×"
        table.rows.append([f"{width}×{height}", f"{fast:.2f}", f"{plain:.2f}", ratio])
    print(f"written to {record('bench/heatmap.py', [table])}")


if __name__ == "__main__":
    main()
