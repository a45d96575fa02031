"""The learned classes' geometry in a stream record (``record["classes"]``).

A student version that learned other classes beside the pool (``student.classes``) answers
them on every frame; the record adds, for each class asked for: a points class's named points
(``{"tip": [x, y]}``, frame pixels, null where the point is not seen), a mask or instances
class's ``area_px`` and ``centroid`` (frame pixels; the centroid null for an empty mask).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.classes import LearnedClass, channel_slices, read_point
from weldpool_core.student.data import FrameGeometry

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np


def chosen_classes(
    learned: Sequence[LearnedClass], names: Sequence[str] | None
) -> tuple[LearnedClass, ...]:
    """The classes a stream adds to its records: ``names`` (None: every class the version
    learned); InvalidInputError naming one it did not learn."""
    if names is None:
        return tuple(learned)
    known = {c.name: c for c in learned}
    missing = [n for n in names if n not in known]
    if missing:
        have = ", ".join(known) or "none"
        raise InvalidInputError(
            f"This student did not learn the class {missing[0]!r} (it learned: {have}); "
            "leave it out of --classes or train a version that learns it."
        )
    return tuple(known[n] for n in names)


def class_geometry(
    probabilities: NDArray[np.float32],
    learned: Sequence[LearnedClass],
    chosen: Sequence[LearnedClass],
    geometry: FrameGeometry,
) -> dict[str, Any]:
    """The ``chosen`` classes' geometry from one frame's E×S×S class probabilities (channels
    in ``learned`` order; see the module doc)."""
    slices = channel_slices(learned)
    found: dict[str, Any] = {}
    for item in chosen:
        channels = probabilities[slices[item.name]]
        if not item.segments:
            found[item.name] = {
                point: _rounded(read_point(channels[i], geometry))
                for i, point in enumerate(item.points)
            }
            continue
        inner = channels[0][geometry.inner_rows, geometry.inner_columns] >= 0.5
        area = float(inner.sum()) / (geometry.scale_x * geometry.scale_y)
        centroid = None
        if inner.any():
            rows, columns = np.nonzero(inner)
            x = (columns.mean() + 0.5) / geometry.scale_x - 0.5
            y = (rows.mean() + 0.5) / geometry.scale_y - 0.5
            centroid = [round(float(x), 2), round(float(y), 2)]
        found[item.name] = {"area_px": round(area, 1), "centroid": centroid}
    return found


def _rounded(point: list[float] | None) -> list[float] | None:
    return None if point is None else [round(point[0], 2), round(point[1], 2)]
