"""Ultralytics YOLO segmentation: ``labels/<split>/<stem>.txt`` beside ``images/<split>/``,
one line ``class x1 y1 x2 y2 …`` per region, coordinates 0–1 of the frame; a vertex is the pixel
it falls in (our export writes pixel centres, which this reads back exactly); class names from
``data.yaml``. A region's holes cannot be written in this format, so none are read."""

from __future__ import annotations

import posixpath
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from weldpool_core.annotations.categories import pool_names
from weldpool_core.annotations.shapes import (
    DAMAGED,
    EDGE_TOLERANCE,
    ImportedLabel,
    OtherShape,
    Parsed,
    Polygons,
    check_vertices,
)
from weldpool_core.annotations.source import Source
from weldpool_core.errors import InvalidInputError
from weldpool_core.outline import Polygon

if TYPE_CHECKING:
    import numpy as np
    import yaml
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np, yaml

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


@dataclass(frozen=True)
class NormalisedPolygons:
    """YOLO's polygons, in 0–1 of a frame whose size is known only when it is rasterised."""

    polygons: list[NDArray[np.float64]]

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        scale = np.array([width, height], np.float64)
        margin = EDGE_TOLERANCE / scale
        for xy in self.polygons:
            outside = ~np.all((xy >= -margin) & (xy <= 1 + margin), axis=1)
            if outside.any():
                x, y = xy[int(np.argmax(outside))]
                raise InvalidInputError(f"The polygon's point ({x:g}, {y:g}) lies outside 0–1.")
        pixels = [
            Polygon([(float(x), float(y)) for x, y in np.clip(np.floor(xy * scale), 0, scale - 1)])
            for xy in self.polygons
        ]
        return Polygons(pixels).mask(height, width)


def _yaml_without_aliases(text: bytes, name: str) -> Any:
    """The YAML document in ``text``, refused when it holds an alias: aliases nested a few
    deep expand a file of a few hundred bytes into gigabytes (each level multiplies), and a
    class list never needs one. The events are read first, so nothing is expanded."""
    try:
        for event in yaml.parse(text, Loader=yaml.SafeLoader):
            if isinstance(event, yaml.AliasEvent):
                raise InvalidInputError(
                    f"{name} uses YAML aliases (*name), which a class list never needs; "
                    "write the names out."
                )
        return yaml.safe_load(text)
    except yaml.YAMLError:
        raise InvalidInputError(f"{name} is not valid YAML.") from None


def _names(source: Source) -> dict[int, str]:
    for candidate in ("data.yaml", "dataset.yaml"):
        if candidate in source:
            data = _yaml_without_aliases(source.read(candidate), candidate)
            names: Any = data.get("names") if isinstance(data, dict) else None
            if isinstance(names, list):
                return {i: str(n) for i, n in enumerate(names)}
            if isinstance(names, dict):
                return {
                    int(k): str(v)
                    for k, v in names.items()
                    if str(k).isascii() and str(k).isdigit()
                }
    return {}


def _image_for(source: Source, label_path: str) -> str | None:
    """``labels/<…>/<stem>.txt`` → ``images/<…>/<stem>.<image suffix>`` (or beside it)."""
    stem = posixpath.splitext(label_path)[0]
    candidates = []
    if stem.startswith("labels/"):
        candidates.append("images/" + stem[len("labels/") :])
    candidates.append(stem.replace("/labels/", "/images/"))
    candidates.append(stem)
    for base in candidates:
        for suffix in IMAGE_SUFFIXES:
            for name in (base + suffix, base + suffix.upper()):
                if name in source:
                    return name
    return None


def read_yolo(source: Source, category: str | None = None) -> Parsed:
    parsed = Parsed()
    names = _names(source)
    pool = pool_names(names.values(), category) if names else {"0"}
    pool_ids = {i for i, n in names.items() if n in pool} if names else {0}
    files = [n for n in source.names if n.endswith(".txt") and n.split("/")[0] == "labels"]
    if not files:
        raise InvalidInputError("No YOLO label files (labels/…/<stem>.txt) were found.")
    for path in files:
        image = _image_for(source, path)
        if image is None:
            parsed.refuse(path, "It has no image of the same stem under images/.")
            continue
        others: list[OtherShape] = []
        try:
            text = source.read(path).decode("utf-8")
            polygons = _lines(text, pool_ids, names, others)
        except (UnicodeDecodeError, InvalidInputError, *DAMAGED) as exc:
            reason = (
                exc.message if isinstance(exc, InvalidInputError) else "It is not text of numbers."
            )
            parsed.refuse(path, reason)
            continue
        if not polygons:
            parsed.attach(None, others)
            continue  # no pool on this frame: nothing to label
        label = ImportedLabel(
            item=path,
            image=posixpath.basename(image),
            shapes=[NormalisedPolygons(polygons)],
            beside=image,
            original_name=posixpath.basename(image),
        )
        parsed.attach(label, others)
        parsed.labels.append(label)
    return parsed


def _lines(
    text: str, pool_ids: set[int], names: dict[int, str], others: list[OtherShape]
) -> list[NDArray[np.float64]]:
    """The pool's polygons of a label file; its other classes' lines go to ``others`` (a line
    of another class that is not a polygon is counted, not refused: it is not the pool's)."""
    polygons = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split()
        if not fields:
            continue
        check_vertices(len(fields) // 2)
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise InvalidInputError(f"Line {number} is not numbers.") from None
        if not values[0].is_integer():
            raise InvalidInputError(f"Line {number}'s class {fields[0]} is not an integer.")
        coordinates = values[1:]
        if int(values[0]) not in pool_ids:
            polygon = len(coordinates) >= 6 and len(coordinates) % 2 == 0
            xy = [np.asarray(coordinates, np.float64).reshape(-1, 2)] if polygon else None
            name = names.get(int(values[0]), fields[0])
            others.append(OtherShape(name, NormalisedPolygons(xy) if xy else None))
            continue
        if len(coordinates) == 4:
            raise InvalidInputError(f"Line {number} is a box, not a polygon; export segments.")
        if len(coordinates) < 6 or len(coordinates) % 2:
            raise InvalidInputError(f"Line {number} needs 3 or more x, y pairs.")
        polygons.append(np.asarray(coordinates, np.float64).reshape(-1, 2))
    return polygons
