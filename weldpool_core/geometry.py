"""The pool's geometry from its mask: area, centroid, length along the travel direction and width
across it — the numbers a welding engineer plots over a run beside the process parameters.

Length and width are the extents of the pool's pixels projected on the travel axis and on the
axis across it (each pixel counts its own size, so a 30×10 rectangle along x is 30 long and 10
wide). The travel direction is the weld run's (an angle in the image, 0° pointing right, 90°
down); without one, each mask's own major axis (its second moments) is used, the pool being
longest along the weld. Millimetres follow from a scale in mm per pixel, given as a number or
measured on a frame: two points a known distance apart (``scale_from_points``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np


@dataclass(frozen=True)
class PoolGeometry:
    """One frame's pool: pixels (and millimetres when the scale is known)."""

    area_px: int
    centroid: tuple[float, float] | None
    length_px: float | None
    width_px: float | None
    travel_deg: float | None
    """The axis length was measured along (the run's, or the mask's major axis)."""

    def in_mm(self, mm_per_px: float | None) -> dict[str, float | None]:
        """Area in mm², length and width in mm; None without a scale or a pool."""
        if not mm_per_px:
            return {"area_mm2": None, "length_mm": None, "width_mm": None}
        return {
            "area_mm2": self.area_px * mm_per_px**2,
            "length_mm": None if self.length_px is None else self.length_px * mm_per_px,
            "width_mm": None if self.width_px is None else self.width_px * mm_per_px,
        }

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class PoolShape:
    """What the geometry needs from a mask, small enough to cache: its area, centroid, major
    axis and the convex hull of its pixel centres (extents along any axis are the hull's)."""

    area_px: int
    centroid: tuple[float, float] | None
    major_deg: float | None
    hull: NDArray[np.float64]  # N × 2 (x, y)
    pixel: float = 1.0
    """The size of one mask pixel in the coordinates of centroid and hull (1: the mask's own)."""

    def measure(self, travel_deg: float | None = None) -> PoolGeometry:
        """The geometry along ``travel_deg`` (the major axis when None)."""
        if self.centroid is None:
            return PoolGeometry(0, None, None, None, travel_deg)
        travel = self.major_deg if travel_deg is None else travel_deg
        assert travel is not None
        theta = math.radians(travel)
        dx = self.hull[:, 0] - self.centroid[0]
        dy = self.hull[:, 1] - self.centroid[1]
        along = dx * math.cos(theta) + dy * math.sin(theta)
        across = -dx * math.sin(theta) + dy * math.cos(theta)
        # Pixel centres span one pixel less than the pixels do (exact along the image axes;
        # within half a pixel at other angles).
        return PoolGeometry(
            area_px=self.area_px,
            centroid=self.centroid,
            length_px=float(along.max() - along.min() + self.pixel),
            width_px=float(across.max() - across.min() + self.pixel),
            travel_deg=float(travel),
        )


def pool_shape(
    mask: NDArray[np.bool_],
    origin: tuple[float, float] = (0.0, 0.0),
    pixel: tuple[float, float] = (1.0, 1.0),
) -> PoolShape:
    """Area, centroid, major axis and hull of a mask (OpenCV's image moments and outer contours:
    no per-pixel arrays).

    ``origin`` and ``pixel`` place the mask in other coordinates: mask pixel (i, j) has its centre
    at ``origin + (j·pixel_x, i·pixel_y)`` — a model's low-resolution mask measured in frame
    pixels. Area, centroid, axis and hull follow; lengths are then exact for a square pixel.
    """
    binary = np.ascontiguousarray(mask, dtype=np.uint8)
    moments = cv2.moments(binary, binaryImage=True)
    px, py = pixel
    area = round(moments["m00"] * px * py)
    if moments["m00"] == 0:
        return PoolShape(0, None, None, np.zeros((0, 2)), pixel=0.5 * (px + py))
    cx = origin[0] + px * moments["m10"] / moments["m00"]
    cy = origin[1] + py * moments["m01"] / moments["m00"]
    # Central second moments → the direction of largest spread, in [0, 180) degrees.
    mu11, mu20, mu02 = moments["mu11"] * px * py, moments["mu20"] * px**2, moments["mu02"] * py**2
    major = math.degrees(0.5 * math.atan2(2 * mu11, mu20 - mu02))
    # Extreme pixel centres lie on the outer boundaries: their hull is the mask's.
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    hull = cv2.convexHull(np.concatenate(contours)).reshape(-1, 2).astype(np.float64)
    hull = hull * np.array([px, py]) + np.array(origin)
    return PoolShape(area, (float(cx), float(cy)), major % 180.0, hull, pixel=0.5 * (px + py))


def pool_geometry(mask: NDArray[np.bool_], travel_deg: float | None = None) -> PoolGeometry:
    """Area, centroid, length along ``travel_deg`` (the mask's major axis when None) and width
    across it, in pixels. An empty mask has area 0 and no other value."""
    return pool_shape(mask).measure(travel_deg)


MIN_SCALE_SPAN_PX = 2.0
"""Two scale points closer than this cannot give a scale worth having."""


def scale_from_points(
    first: tuple[float, float], second: tuple[float, float], distance_mm: float
) -> float:
    """The image scale in mm per pixel from two points (frame pixels) ``distance_mm`` apart:
    the distance over the points' Euclidean separation. Raises ``InvalidInputError`` for
    points closer than ``MIN_SCALE_SPAN_PX`` or a distance that is not positive."""
    span = math.hypot(second[0] - first[0], second[1] - first[1])
    if not math.isfinite(span) or span < MIN_SCALE_SPAN_PX:
        raise InvalidInputError(
            f"The two scale points are {span:.1f} px apart; place them at least "
            f"{MIN_SCALE_SPAN_PX:g} px apart, at the ends of a known length."
        )
    if not (math.isfinite(distance_mm) and distance_mm > 0):
        raise InvalidInputError("The known distance must be a positive number of millimetres.")
    return distance_mm / span
