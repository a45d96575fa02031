"""Agreement of the classes beside the pool, between annotators who labelled one frame apart
(``app.review.agreement``): per class of the label configuration,

- ``mask`` and ``instances``: the IoU of the class's union mask (every object of it, one
  mask); ``instances`` also how many objects more one annotator drew than the other;
- ``points``: per named point, the distance in px (from each of one annotator's points of that
  name to the nearest of the other's, both ways, as the pool's keypoints are measured);
- the frame's tags and attributes: which of them the annotators do not all give alike.

A class neither annotator of a pair drew is not measured for that pair; one drawn by one only
has IoU 0 (its points, no partner, no distance). A frame's figure of a class is the mean over
its pairs, a run's the mean over its frames.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from weldpool_core.outline import rle_mask

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

Figures = dict[str, Any]
"""One class's figures: ``{"class", "kind", "pairs", "iou", "count_diff", "points_px"}``."""


def nearest_px(a: list[Any] | None, b: list[Any] | None) -> float | None:
    """Mean distance from each point of one set to the nearest of the other, both ways."""
    if not a or not b:
        return None
    one = np.asarray(a, float)[:, None, :] - np.asarray(b, float)[None, :, :]
    distances = np.linalg.norm(one, axis=2)
    return float((distances.min(axis=1).mean() + distances.min(axis=0).mean()) / 2)


def _kind(name: str, objects: list[dict[str, Any]], kinds: dict[str, str]) -> str:
    """The class's kind as configured; for a class no longer configured, as its objects read."""
    if name in kinds:
        return kinds[name]
    return "points" if any("points" in o for o in objects) else "instances"


def _union(objects: list[dict[str, Any]]) -> Any:
    """One mask of every region among ``objects`` (None when there is none)."""
    union = None
    for item in objects:
        if isinstance(item.get("rle"), dict):
            mask = rle_mask(item["rle"])
            union = mask if union is None else union | mask
    return union


def _iou(a: Any, b: Any) -> float | None:
    if a is None and b is None:
        return None
    if a is None or b is None:
        return 0.0
    union = int(np.logical_or(a, b).sum())
    return float(np.logical_and(a, b).sum()) / union if union else None


def _points(objects: list[dict[str, Any]]) -> dict[str, list[list[float]]]:
    """The class's points by name, over all its objects."""
    named: dict[str, list[list[float]]] = {}
    for item in objects:
        for name, xy in (item.get("points") or {}).items():
            named.setdefault(str(name), []).append([float(xy[0]), float(xy[1])])
    return named


def _by_class(objects: list[Any] | None) -> dict[str, list[dict[str, Any]]]:
    grouped: dict[str, list[dict[str, Any]]] = {}
    for item in objects or []:
        if isinstance(item, dict) and isinstance(item.get("class"), str):
            grouped.setdefault(item["class"], []).append(item)
    return grouped


def pair_figures(
    a: list[Any] | None, b: list[Any] | None, kinds: dict[str, str]
) -> dict[str, Figures]:
    """The figures of each class either label of one pair holds (module doc)."""
    one, other = _by_class(a), _by_class(b)
    figures: dict[str, Figures] = {}
    for name in sorted(one.keys() | other.keys()):
        mine, theirs = one.get(name, []), other.get(name, [])
        kind = _kind(name, mine + theirs, kinds)
        entry: Figures = {"class": name, "kind": kind, "pairs": 1}
        entry |= {"iou": None, "count_diff": None, "points_px": {}}
        if kind == "points":
            here, there = _points(mine), _points(theirs)
            entry["points_px"] = {
                point: px
                for point in sorted(here.keys() & there.keys())
                if (px := nearest_px(here[point], there[point])) is not None
            }
        else:
            entry["iou"] = _iou(_union(mine), _union(theirs))
            if kind == "instances":
                entry["count_diff"] = abs(len(mine) - len(theirs))
        figures[name] = entry
    return figures


def _mean(values: Iterable[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return statistics.fmean(present) if present else None


def mean_figures(many: list[dict[str, Figures]]) -> list[Figures]:
    """Each class's figures averaged over pairs (or frames), by class name."""
    by_class: dict[str, list[Figures]] = {}
    for figures in many:
        for name, entry in figures.items():
            by_class.setdefault(name, []).append(entry)
    means = []
    for name, entries in sorted(by_class.items()):
        names = sorted({p for e in entries for p in e["points_px"]})
        means.append(
            {
                "class": name,
                "kind": entries[0]["kind"],
                "pairs": sum(e["pairs"] for e in entries),
                "iou": _mean(e["iou"] for e in entries),
                "count_diff": _mean(e["count_diff"] for e in entries),
                "points_px": {p: _mean(e["points_px"].get(p) for e in entries) for p in names},
            }
        )
    return means


def frame_fields_differ(frame_tags: list[dict[str, Any] | None]) -> dict[str, list[str]]:
    """The tags and the attributes the labelled annotators of one frame do not all give alike
    (``frame_tags``: each one's ``{"tags", "attributes"}`` column, NULL for none)."""
    held = [t or {} for t in frame_tags]
    tags = [set(t.get("tags") or []) for t in held]
    attributes = [t.get("attributes") or {} for t in held]
    names = {n for a in attributes for n in a}
    return {
        "tags": sorted(set().union(*tags) - set.intersection(*tags)) if tags else [],
        "attributes": sorted(n for n in names if len({repr(a.get(n)) for a in attributes}) > 1),
    }


def frame_class_agreement(
    labels: list[tuple[list[Any] | None, dict[str, Any] | None]], kinds: dict[str, str]
) -> tuple[list[Figures], dict[str, list[str]]]:
    """One frame's per-class figures (the mean over every pair of ``labels``, each an
    annotator's ``(objects, frame_tags)``) and the tags and attributes that differ."""
    pairs = [pair_figures(a[0], b[0], kinds) for a, b in itertools.combinations(labels, 2)]
    return mean_figures(pairs), frame_fields_differ([tags for _, tags in labels])
