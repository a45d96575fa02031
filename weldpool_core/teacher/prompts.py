"""From DINO attention to SAM2 prompts: the paper's three configurations.

``none``: no prompt (SAM2's automatic masks; the teacher keeps the best-scoring one).
``center``: one positive point at the centre of the thresholded attention map.
``heuristic`` (default): DBSCAN groups the attended patches into regions; the region with the
most attention gives a bounding box (with a margin), positive points at its strongest, spread
out patches, and negative points at clearly unattended patches outside the box.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import DBSCAN

from weldpool_core.teacher.dino import AttentionMaps
from weldpool_core.teacher.prompt_names import PromptName
from weldpool_core.teacher.sam2 import Prompts


@dataclass(frozen=True)
class HeuristicParams:
    """Parameters of the ``heuristic`` prompt configuration (distances in patches).

    Attributes:
        eps: DBSCAN neighbourhood radius; 1.5 joins patches that touch, diagonals included.
        min_samples: attended patches a DBSCAN core point needs within ``eps``.
        positive_points: positive clicks placed on the strongest attention in the region.
        negative_points: negative clicks placed on clearly unattended patches.
        box_margin: the region's box grows by this fraction of its size on every side.
        min_point_separation: positive (and negative) points keep at least this distance.
        negative_quantile: patches whose attention is below this quantile count as "clearly
            unattended".
    """

    eps: float = 1.5
    min_samples: int = 4
    positive_points: int = 3
    negative_points: int = 2
    box_margin: float = 0.1
    min_point_separation: float = 3.0
    negative_quantile: float = 0.2


def _to_image(rows_cols: NDArray[np.float64], attention: AttentionMaps) -> NDArray[np.float64]:
    """Patch (row, col) centres → image (x, y) pixel coordinates."""
    grid_h, grid_w = attention.grid
    height, width = attention.image_size
    x = (rows_cols[:, 1] + 0.5) * width / grid_w
    y = (rows_cols[:, 0] + 0.5) * height / grid_h
    return np.stack([x, y], axis=1)


def _spread(
    candidates: NDArray[np.int64], order: NDArray[np.int64], count: int, separation: float
) -> NDArray[np.int64]:
    """Up to ``count`` candidates taken in ``order``, each ``separation`` from those taken."""
    chosen: list[NDArray[np.int64]] = []
    for index in order:
        point = candidates[index]
        if all(np.hypot(*(point - other)) >= separation for other in chosen):
            chosen.append(point)
            if len(chosen) == count:
                break
    return np.array(chosen, dtype=np.int64).reshape(-1, 2)


def none_prompts(attention: AttentionMaps, params: HeuristicParams | None = None) -> Prompts:
    """No prompt at all: SAM2 segments automatically (see ``Teacher``)."""
    return Prompts()


def center_prompts(attention: AttentionMaps, params: HeuristicParams | None = None) -> Prompts:
    """One positive point at the centroid of the thresholded attention map."""
    rows_cols = np.argwhere(attention.attended).astype(np.float64)
    if len(rows_cols) == 0:  # a flat map: the image centre
        height, width = attention.image_size
        return Prompts(((width / 2, height / 2),), (1,))
    x, y = _to_image(rows_cols.mean(axis=0, keepdims=True), attention)[0]
    return Prompts(((float(x), float(y)),), (1,))


def heuristic_prompts(attention: AttentionMaps, params: HeuristicParams | None = None) -> Prompts:
    """The paper's heuristic: DBSCAN region → box, positive and negative points."""
    params = params or HeuristicParams()
    attended = np.argwhere(attention.attended)
    if len(attended) < params.min_samples:
        return center_prompts(attention)
    labels = DBSCAN(eps=params.eps, min_samples=params.min_samples).fit_predict(attended)
    clusters = [c for c in np.unique(labels) if c >= 0]
    if not clusters:
        return center_prompts(attention)
    strength = attention.mean
    mass = [strength[tuple(attended[labels == c].T)].sum() for c in clusters]
    region = attended[labels == clusters[int(np.argmax(mass))]]

    (top, left), (bottom, right) = region.min(axis=0), region.max(axis=0) + 1
    margin_y, margin_x = params.box_margin * (bottom - top), params.box_margin * (right - left)
    grid_h, grid_w = attention.grid
    box_patches = (
        max(0.0, left - margin_x),
        max(0.0, top - margin_y),
        min(float(grid_w), right + margin_x),
        min(float(grid_h), bottom + margin_y),
    )
    height, width = attention.image_size
    box = (
        box_patches[0] * width / grid_w,
        box_patches[1] * height / grid_h,
        box_patches[2] * width / grid_w,
        box_patches[3] * height / grid_h,
    )

    order = np.argsort(-strength[tuple(region.T)], kind="stable")
    positives = _spread(region, order, params.positive_points, params.min_point_separation)

    rows, cols = np.mgrid[:grid_h, :grid_w]
    outside = (
        (cols + 0.5 < box_patches[0])
        | (cols + 0.5 > box_patches[2])
        | (rows + 0.5 < box_patches[1])
        | (rows + 0.5 > box_patches[3])
    )
    quiet = outside & (strength <= np.quantile(strength, params.negative_quantile))
    quiet_cells = np.argwhere(quiet)
    negatives = _spread(
        quiet_cells,
        np.argsort(strength[tuple(quiet_cells.T)], kind="stable"),
        params.negative_points,
        params.min_point_separation,
    )

    points = [*_to_image(positives.astype(np.float64), attention)]
    points += [*_to_image(negatives.astype(np.float64), attention)]
    labels_out = (1,) * len(positives) + (0,) * len(negatives)
    return Prompts(tuple((float(x), float(y)) for x, y in points), labels_out, box)


PromptStrategy = Callable[[AttentionMaps, HeuristicParams | None], Prompts]

PROMPT_STRATEGIES: dict[PromptName, PromptStrategy] = {
    "none": none_prompts,
    "center": center_prompts,
    "heuristic": heuristic_prompts,
}
