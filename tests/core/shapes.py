"""Synthetic masks for the core tests: random pool-like blobs and shapes with known corners."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from weldpool_core.heatmap import HeatmapResult

SIZE = 256


def polygon_mask(points: NDArray[np.float64], size: int = SIZE) -> NDArray[np.bool_]:
    """A filled polygon (sub-pixel vertices) as a boolean mask."""
    canvas = np.zeros((size, size), np.uint8)
    cv2.fillPoly(canvas, [np.round(points * 16).astype(np.int32)], 1, shift=4)
    return canvas.astype(bool)


def pool_blob(seed: int, size: int = SIZE, margin: int = 20) -> NDArray[np.bool_]:
    """A random pool-like blob: a wobbly ellipse, sometimes with a notch; never near the border."""
    rng = np.random.default_rng(seed)
    phi = np.linspace(0, 2 * math.pi, 400, endpoint=False)
    radius = np.ones_like(phi)
    for order in range(2, 6):
        radius += rng.uniform(-0.1, 0.1) * np.cos(order * phi + rng.uniform(0, 2 * math.pi))
    if rng.random() < 0.5:
        centre = rng.uniform(0, 2 * math.pi)
        radius -= 0.25 * np.exp(-((np.angle(np.exp(1j * (phi - centre))) / 0.12) ** 2))
    scale = rng.uniform(30, 60)
    squash = rng.uniform(0.6, 1.0)
    cx, cy = rng.uniform(size / 2 - 15, size / 2 + 15, 2)
    points = np.stack(
        [cx + scale * radius * np.cos(phi), cy + scale * squash * radius * np.sin(phi)], axis=1
    )
    mask = polygon_mask(points, size)
    rows, cols = np.nonzero(mask)
    assert rows.min() >= margin and cols.min() >= margin
    assert rows.max() < size - margin and cols.max() < size - margin
    return mask


def ellipse_mask(axes: tuple[int, int] = (90, 50), size: int = SIZE) -> NDArray[np.bool_]:
    canvas = np.zeros((size, size), np.uint8)
    cv2.ellipse(canvas, (size // 2, size // 2), axes, 0, 0, 360, 1, -1)
    return canvas.astype(bool)


SQUARE = np.array([[70.0, 60.0], [190.0, 60.0], [190.0, 180.0], [70.0, 180.0]])
TRIANGLE = np.array([[128.0, 40.0], [220.0, 200.0], [36.0, 200.0]])
TEARDROP_TIP = np.array([230.0, 128.0])


def teardrop_mask(size: int = SIZE) -> NDArray[np.bool_]:
    """A round end on the left and one sharp tip on the right, at ``TEARDROP_TIP``."""
    canvas = np.zeros((size, size), np.uint8)
    cv2.circle(canvas, (100, 128), 50, 1, -1)
    cv2.fillPoly(canvas, [np.array([[100, 78], [230, 128], [100, 178]], np.int32)], 1)
    return canvas.astype(bool)


def arc_positions(result: HeatmapResult) -> tuple[NDArray[np.float64], float]:
    """Arc position of each keypoint along the result's contour, and the perimeter."""
    contour = result.contour
    steps = np.linalg.norm(np.diff(contour, axis=0, append=contour[:1]), axis=1)
    arcs = np.concatenate(([0.0], np.cumsum(steps)[:-1]))
    nearest = np.argmin(
        np.linalg.norm(contour[None, :, :] - result.keypoints[:, None, :], axis=2), axis=1
    )
    return arcs[nearest], float(steps.sum())


def centroid(result: HeatmapResult) -> tuple[float, float]:
    """Centroid of the area inside the result's contour (the centre of the order rule)."""
    moments = cv2.moments(result.contour.astype(np.float32))
    return moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]
