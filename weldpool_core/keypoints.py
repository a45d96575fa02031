"""Keypoints of a weld pool: their stable order, and the modes of a (predicted) heatmap.

Coordinates are ``(x, y)`` in pixels, the origin at the centre of the top-left pixel; ``y`` grows
downwards, so an increasing image angle ``atan2(y, x)`` turns clockwise on screen.

Order rule (shared by Algorithm 1 and the student): keypoints are sorted by their angle around a
centre (the pool's centroid), clockwise on screen, starting from the direction ``start_deg``
(default 180°: straight left, the middle of the pool's trailing edge, where Algorithm 1 puts no
keypoint: its k = 4 anchors sit at the diagonals, so keypoint 0 is the back-top corner, then
front-top, front-bottom and back-bottom, and small changes of shape never move one across the
start).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeAlias

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

ORDER_START_DEG = 180.0
"""Default start direction of the order rule, in image degrees (180°: left on screen)."""

Points: TypeAlias = "NDArray[np.float64]"
"""k×2 array of ``(x, y)`` keypoints."""


def angles_around(
    points: NDArray[Any], centre: tuple[float, float], start_deg: float = ORDER_START_DEG
) -> NDArray[np.float64]:
    """Angle of each point around ``centre``, clockwise on screen from ``start_deg``, in [0, 2π)."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    raw = np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0])
    angles: NDArray[np.float64] = np.mod(raw - math.radians(start_deg), 2 * math.pi)
    return angles


def order_by_angle(
    points: NDArray[Any], centre: tuple[float, float], start_deg: float = ORDER_START_DEG
) -> NDArray[np.intp]:
    """Indices that put ``points`` in the order rule of this module (see the module doc)."""
    return np.argsort(angles_around(points, centre, start_deg), kind="stable")


@dataclass(frozen=True)
class ModeParams:
    """How ``keypoints_from_heatmap`` finds and refines modes.

    Attributes:
        min_distance: non-maximum suppression radius in pixels; two modes are never closer.
        min_relative_peak: a mode must reach this fraction of the heatmap's maximum.
        min_peak: and this absolute value (so an all-zero prediction has no modes).
        refine_radius: half-size in pixels of the window used for sub-pixel refinement.
        refine_level: the refinement is the centroid of the window's values above this fraction
            of the mode's peak (its upper part only, so a neighbouring mode does not pull it).
        order_start_deg: start direction of the order rule.
    """

    min_distance: float = 5.0
    min_relative_peak: float = 0.1
    min_peak: float = 1e-3
    refine_radius: int = 3
    refine_level: float = 0.5
    order_start_deg: float = ORDER_START_DEG

    def __post_init__(self) -> None:
        if self.min_distance <= 0 or self.refine_radius < 1:
            raise InvalidInputError("min_distance and refine_radius must be positive.")
        if not 0 <= self.min_relative_peak <= 1 or not 0 <= self.refine_level < 1:
            raise InvalidInputError("min_relative_peak and refine_level must lie in [0, 1).")


def _heatmap_and_centre(
    heatmap: NDArray[Any], centre: tuple[float, float] | None
) -> tuple[NDArray[np.float32], tuple[float, float] | None]:
    array = np.asarray(heatmap)
    if array.ndim == 3 and array.shape[2] in (1, 2):
        if centre is None and array.shape[2] == 2:
            moments = cv2.moments((array[:, :, 1] >= 0.5).astype(np.uint8), binaryImage=True)
            if moments["m00"] > 0:
                centre = (moments["m10"] / moments["m00"], moments["m01"] / moments["m00"])
        array = array[:, :, 0]
    if array.ndim != 2 or array.size == 0:
        raise InvalidInputError(
            f"A heatmap must be H×W or H×W×2 (heatmap, mask), not of shape {array.shape}."
        )
    values = np.ascontiguousarray(array, dtype=np.float32)
    if not np.isfinite(values).all():
        values = np.nan_to_num(values, nan=0.0)
    return values, centre


def _refine(values: NDArray[np.float32], x: int, y: int, params: ModeParams) -> tuple[float, float]:
    """Sub-pixel position of the mode at pixel (x, y): centroid of its upper part."""
    r = params.refine_radius
    y0, y1 = max(y - r, 0), min(y + r + 1, values.shape[0])
    x0, x1 = max(x - r, 0), min(x + r + 1, values.shape[1])
    window = values[y0:y1, x0:x1].astype(np.float64)
    weights = np.clip(window - params.refine_level * float(values[y, x]), 0.0, None)
    total = float(weights.sum())
    if total <= 0:
        return float(x), float(y)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    return float((weights * xs).sum() / total), float((weights * ys).sum() / total)


def keypoints_from_heatmap(
    heatmap: NDArray[Any],
    k: int = 4,
    params: ModeParams | None = None,
    centre: tuple[float, float] | None = None,
) -> Points:
    """The k strongest modes of a heatmap, sub-pixel, in the order rule; up to k (m×2, m ≤ k).

    Modes are 3×3 local maxima above the thresholds of ``params``, kept strongest first with
    non-maximum suppression, then refined. ``heatmap`` is H×W, or H×W×2 (heatmap, mask) as
    Algorithm 1 and the student write it. The order's centre is ``centre`` if given, else the
    centroid of the mask channel (≥ 0.5), else the mean of the modes.
    """
    if k < 1:
        raise InvalidInputError(f"k must be at least 1, not {k}.")
    params = params or ModeParams()
    values, centre = _heatmap_and_centre(heatmap, centre)
    peak = float(values.max())
    floor = max(params.min_peak, params.min_relative_peak * peak)
    if peak < floor or peak <= 0:
        return np.zeros((0, 2), np.float64)
    is_max = (values == cv2.dilate(values, np.ones((3, 3), np.uint8))) & (values >= floor)
    flat = np.flatnonzero(is_max)  # in raster order
    ranked = flat[np.argsort(-values.ravel()[flat], kind="stable")]  # strongest first
    ys, xs = np.divmod(ranked, values.shape[1])
    chosen: list[tuple[int, int]] = []
    alive = np.ones(len(xs), bool)
    while len(chosen) < k and alive.any():
        first = int(np.argmax(alive))
        x, y = int(xs[first]), int(ys[first])
        chosen.append((x, y))
        alive &= (xs - x) ** 2 + (ys - y) ** 2 >= params.min_distance**2
    modes = np.array([_refine(values, x, y, params) for x, y in chosen], np.float64)
    if centre is None:
        centre = (float(modes[:, 0].mean()), float(modes[:, 1].mean()))
    ordered: Points = modes[order_by_angle(modes, centre, params.order_start_deg)]
    return ordered
