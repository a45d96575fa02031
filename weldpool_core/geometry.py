"""The pool's geometry from its mask: area, centroid, length along the travel direction and width
across it — the numbers a welding engineer plots over a run beside the process parameters.

Length and width are the extents of the pool's pixels projected on the travel axis and on the
axis across it (each pixel counts its own size, so a 30×10 rectangle along x is 30 long and 10
wide). The travel direction is the weld run's (an angle in the image, 0° pointing right, 90°
down); without one, each mask's own major axis (its second moments) is used, the pool being
longest along the weld. Millimetres follow from a scale in mm per pixel.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray


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


def pool_geometry(mask: NDArray[np.bool_], travel_deg: float | None = None) -> PoolGeometry:
    """Area, centroid, length along ``travel_deg`` (the mask's major axis when None) and width
    across it, in pixels. An empty mask has area 0 and no other value."""
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return PoolGeometry(0, None, None, None, travel_deg)
    x = xs.astype(np.float64)
    y = ys.astype(np.float64)
    cx, cy = float(x.mean()), float(y.mean())
    if travel_deg is None:
        travel_deg = _major_axis_deg(x - cx, y - cy)
    theta = math.radians(travel_deg)
    along = (x - cx) * math.cos(theta) + (y - cy) * math.sin(theta)
    across = -(x - cx) * math.sin(theta) + (y - cy) * math.cos(theta)
    # Pixel centres span one pixel less than the pixels do (exact along the image axes; within
    # half a pixel at other angles).
    return PoolGeometry(
        area_px=int(xs.size),
        centroid=(cx, cy),
        length_px=float(along.max() - along.min() + 1.0),
        width_px=float(across.max() - across.min() + 1.0),
        travel_deg=float(travel_deg),
    )


def _major_axis_deg(dx: NDArray[np.float64], dy: NDArray[np.float64]) -> float:
    """The direction of largest spread (second moments), in [0, 180) degrees."""
    sxx, syy, sxy = float(np.mean(dx * dx)), float(np.mean(dy * dy)), float(np.mean(dx * dy))
    return math.degrees(0.5 * math.atan2(2 * sxy, sxx - syy)) % 180.0
