"""The other classes over a weld run: per frame, from its label's objects, each class's object
count, summed area (mask and instances classes) and mean point positions (points classes),
and the frame's tags; the classes and tags the label configuration lists, for the page's
choices."""

from __future__ import annotations

from typing import Any

from app.core.models import Label
from app.labelconfig.schemas import POOL
from app.labelconfig.service import Current


def configured(config: Current) -> dict[str, Any]:
    """The classes beside the pool (name, kind, point names) and the frame tags in force."""
    return {
        "classes": [
            {"name": c["name"], "kind": c["kind"], "point_names": c.get("point_names")}
            for c in config.config["classes"]
            if c["name"] != POOL
        ],
        "frame_tags": list(config.config.get("frame_tags", [])),
    }


def frame_classes(label: Label | None, scale: float | None) -> dict[str, Any]:
    """A frame's ``classes`` ({name: {count, area_px, area_mm2, points}}) and ``tags`` from
    its label (none without one): areas are the objects' stored areas summed, a points class's
    each named point the mean of its objects' (pixels)."""
    figures: dict[str, dict[str, Any]] = {}
    sums: dict[str, dict[str, list[float]]] = {}
    for item in (label.objects if label is not None else None) or []:
        if not isinstance(item, dict) or not isinstance(item.get("class"), str):
            continue
        name = item["class"]
        entry = figures.setdefault(name, {"count": 0, "area_px": None, "points": {}})
        entry["count"] += 1
        if isinstance(item.get("area"), int | float):
            entry["area_px"] = (entry["area_px"] or 0) + item["area"]
        for point, xy in (item.get("points") or {}).items():
            total = sums.setdefault(name, {}).setdefault(point, [0.0, 0.0, 0.0])
            total[0], total[1], total[2] = total[0] + xy[0], total[1] + xy[1], total[2] + 1
    for name, entry in figures.items():
        area = entry["area_px"]
        entry["area_mm2"] = area * scale * scale if area is not None and scale else None
        entry["points"] = {p: [x / n, y / n] for p, (x, y, n) in sums.get(name, {}).items()}
    held = (label.frame_tags if label is not None else None) or {}
    return {"classes": figures, "tags": list(held.get("tags") or [])}
