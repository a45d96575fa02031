"""LabelMe JSON, one file per image: ``shapes`` of type ``polygon``, ``rectangle``, ``circle``,
``mask`` (a PNG of the box between its two points) and ``point`` (a keypoint placed by hand:
validation keypoints; the label's own where its ``description`` is ``label``, as our export
writes them); the image beside the file (``imagePath``) or inside it (``imageData``).

Other labels: a region shape is an object, with its ``flags`` and ``attributes`` (an extra key,
which LabelMe keeps) as attributes; the ``point`` shapes of a label with one ``group_id`` (or
none) are one points object, each point named by its ``description`` (else 1, 2, … in order).
The file's ``flags`` that are true are the frame's tags, its ``attributes`` (an extra key) the
frame's attributes."""

from __future__ import annotations

import base64
import binascii
import math
import posixpath
from typing import TYPE_CHECKING, Any

from weldpool_core.annotations.categories import pool_names
from weldpool_core.annotations.shapes import (
    DAMAGED,
    ImportedLabel,
    OtherShape,
    Parsed,
    PartialMask,
    Polygons,
    Shape,
    check_vertices,
)
from weldpool_core.annotations.source import Source
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import decode_mask_png
from weldpool_core.outline import Polygon

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

CIRCLE_VERTICES = 64


def labelme_files(source: Source) -> list[str]:
    if source.primary:
        return [source.primary]
    return [n for n in source.names if n.lower().endswith(".json") and n != "manifest.json"]


def read_labelme(source: Source, category: str | None = None) -> Parsed:
    parsed = Parsed()
    documents = []
    for name in labelme_files(source):
        try:
            document = source.read_json(name)
        except InvalidInputError as exc:
            parsed.refuse(name, exc.message)
            continue
        if not isinstance(document, dict) or not isinstance(document.get("shapes"), list):
            parsed.refuse(name, "The file is not LabelMe JSON: it needs a `shapes` list.")
            continue
        # The image is read again with its batch (``ImportedLabel.loaded``), not held by all.
        data = document.pop("imageData", None)
        document["imageData"] = bool(isinstance(data, str) and data)
        documents.append((name, document))
    if not documents and not parsed.refused:
        raise InvalidInputError("No LabelMe files (JSON with shapes) were found.")
    every = [str(s.get("label")) for _, d in documents for s in d["shapes"] if isinstance(s, dict)]
    pool = pool_names(every, category)
    for name, document in documents:
        try:
            label = _label(name, document, pool, parsed)
        except DAMAGED:
            parsed.refuse(name, "It holds values of the wrong type or size.")
            continue
        if label is not None:
            parsed.labels.append(label)
    return parsed


def _label(
    name: str, document: dict[str, Any], pool: set[str], parsed: Parsed
) -> ImportedLabel | None:
    image = document.get("imagePath")
    if not isinstance(image, str) or not image:
        image = posixpath.splitext(posixpath.basename(name))[0] + ".png"
    height, width = document.get("imageHeight"), document.get("imageWidth")
    label = ImportedLabel(
        item=name,
        image=posixpath.basename(image.replace("\\", "/")),
        size=(height, width) if isinstance(height, int) and isinstance(width, int) else None,
        embedded=name if document.get("imageData") is True else None,
        beside=posixpath.join(posixpath.dirname(name), image.replace("\\", "/")),
        original_name=posixpath.basename(image.replace("\\", "/")),
    )
    points: list[list[float]] = []
    own: list[list[float]] = []  # the label's own keypoints (our export's)
    others: list[OtherShape] = []
    grouped: dict[tuple[str, Any], OtherShape] = {}  # points objects by label and group
    for index, shape in enumerate(document["shapes"]):
        item = f"{name}: shape {index + 1}"
        if not isinstance(shape, dict):
            parsed.refuse(item, "A shape must be a JSON object.")
            return None
        if not isinstance(shape.get("label"), str) or shape.get("label") not in pool:
            if shape.get("shape_type") == "point":
                _add_point(shape, grouped, others)
            else:
                others.append(_other(shape))
            continue
        try:
            kind = shape.get("shape_type") or "polygon"
            xy = _xy(shape.get("points"))
            if kind == "point" and shape.get("description") == LABEL_KEYPOINT:
                own += [[float(x), float(y)] for x, y in xy]
            elif kind == "point":
                points += [[float(x), float(y)] for x, y in xy]
            else:
                label.shapes.append(_shape(kind, xy, shape.get("mask")))
        except InvalidInputError as exc:
            parsed.refuse(item, exc.message)
            return None
    label.validation_keypoints = points or None
    label.keypoints = own or None
    flags, attributes = document.get("flags"), document.get("attributes")
    if isinstance(flags, dict):
        label.tags = [str(tag) for tag, on in flags.items() if on is True]
    if isinstance(attributes, dict):
        label.frame_attributes = attributes
    kept = label if label.shapes or points or own else None
    parsed.attach(kept, others)
    return kept


def _other(shape: dict[str, Any]) -> OtherShape:
    """A shape of another label with its attributes (its area None where it has none:
    lines)."""
    other = OtherShape(str(shape.get("label")), attributes=shape_attributes(shape))
    try:
        xy = _xy(shape.get("points"))
        other.shape = _shape(shape.get("shape_type") or "polygon", xy, shape.get("mask"))
    except (InvalidInputError, *DAMAGED):
        pass
    return other


def shape_attributes(shape: dict[str, Any]) -> dict[str, Any]:
    """A shape's attributes: its ``flags`` (flag attributes), then its ``attributes`` object
    (every other kind: LabelMe keeps a shape's keys it does not know)."""
    flags, attributes = shape.get("flags"), shape.get("attributes")
    given = {str(k): v for k, v in flags.items()} if isinstance(flags, dict) else {}
    return given | (
        {str(k): v for k, v in attributes.items()} if isinstance(attributes, dict) else {}
    )


def _add_point(
    shape: dict[str, Any], grouped: dict[tuple[str, Any], OtherShape], others: list[OtherShape]
) -> None:
    """A ``point`` shape of another label into its points object: the label's points with one
    ``group_id`` (or with none) are one object; a point is named by its ``description``, else
    numbered in order (1, 2, …)."""
    name, group = str(shape.get("label")), shape.get("group_id")
    key = (name, group if isinstance(group, int | str) else None)
    other = grouped.get(key)
    if other is None:
        other = grouped[key] = OtherShape(name, points={})
        others.append(other)
    other.attributes |= shape_attributes(shape)
    try:
        (x, y), *_ = _xy(shape.get("points"))
    except (InvalidInputError, ValueError):
        return
    assert other.points is not None  # made above
    description = shape.get("description")
    point = description.strip() if isinstance(description, str) else ""
    other.points[point or str(len(other.points) + 1)] = [x, y]


def _xy(points: Any) -> list[tuple[float, float]]:
    check_vertices(len(points) if isinstance(points, list) else 0)
    if not (
        isinstance(points, list)
        and points
        and all(
            isinstance(p, list)
            and len(p) == 2
            and all(isinstance(v, int | float) and math.isfinite(v) for v in p)
            for p in points
        )
    ):
        raise InvalidInputError("The shape's points are not a list of [x, y].")
    return [(float(x), float(y)) for x, y in points]


def _shape(kind: str, xy: list[tuple[float, float]], mask: Any) -> Shape:
    if kind == "polygon":
        if len(xy) < 3:
            raise InvalidInputError("A polygon needs 3 or more points.")
        return Polygons([Polygon(xy)])
    if kind == "rectangle" and len(xy) == 2:
        (x0, y0), (x1, y1) = xy
        return Polygons([Polygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])])
    if kind == "circle" and len(xy) == 2:
        (cx, cy), (px, py) = xy
        radius = math.hypot(px - cx, py - cy)
        angles = np.linspace(0, 2 * np.pi, CIRCLE_VERTICES, endpoint=False)
        ring = [(cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in angles]
        return Polygons([Polygon(ring)])
    if kind == "mask" and len(xy) == 2 and isinstance(mask, str):
        try:
            pixels = decode_mask_png(base64.b64decode(mask, validate=True))
        except (binascii.Error, ValueError):
            raise InvalidInputError("The mask shape's data is not base64.") from None
        return PartialMask(
            pixels, left=round(min(xy[0][0], xy[1][0])), top=round(min(xy[0][1], xy[1][1]))
        )
    raise InvalidInputError(f"A {kind} shape has no pool area to import.")


LABEL_KEYPOINT = "label"
"""The ``description`` of a pool ``point`` shape that is one of the label's own keypoints (as
our export writes them); any other pool point was placed by hand (validation keypoints)."""
LABELME_VERSION = "5.4.1"


def labelme_mask(label: str, pixels: NDArray[np.bool_], left: int, top: int) -> dict[str, Any]:
    """A ``mask`` shape: the PNG (0/255) of a box's pixels whose top-left is at (``left``,
    ``top``), between the box's first and last pixels, as LabelMe writes one."""
    from weldpool_core.io import encode_mask_png

    height, width = pixels.shape
    return {
        "label": label,
        "points": [[float(left), float(top)], [float(left + width - 1), float(top + height - 1)]],
        "group_id": None,
        "description": "",
        "shape_type": "mask",
        "flags": {},
        "mask": base64.b64encode(encode_mask_png(pixels)).decode("ascii"),
    }


def labelme_point(label: str, xy: list[float], description: str = "") -> dict[str, Any]:
    """A ``point`` shape."""
    return {
        "label": label,
        "points": [[float(xy[0]), float(xy[1])]],
        "group_id": None,
        "description": description,
        "shape_type": "point",
        "flags": {},
    }


def labelme_document(
    image: str, height: int, width: int, shapes: list[dict[str, Any]], flags: dict[str, bool]
) -> dict[str, Any]:
    """A LabelMe file for the image ``image`` beside it (no ``imageData``)."""
    return {
        "version": LABELME_VERSION,
        "flags": flags,
        "shapes": shapes,
        "imagePath": image,
        "imageData": None,
        "imageHeight": height,
        "imageWidth": width,
    }
