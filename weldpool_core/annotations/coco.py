"""COCO instance (and keypoint) files: polygons, compressed and uncompressed RLE, ``iscrowd``.

Frames: an image's ``tags`` (a list of names) and ``attributes`` (an object) are its frame tags
and attributes. Other categories: an annotation's ``attributes`` (an object, as CVAT's COCO
export writes them) are its object's; a category with ``keypoints`` names is a points class,
each of its annotations one object whose points are the named keypoints with v > 0.

Every pool annotation of an image joins its mask (a crowd region too: for a pool, ``iscrowd``
only says the region is given as RLE). Keypoints: in a weldpool export (``info.description``)
``keypoints`` are the label's own and ``validation_keypoints`` the hand-placed ones; in any
other COCO file the pool's keypoints were placed by hand in another tool, so they become
validation keypoints.
"""

from __future__ import annotations

import posixpath
from typing import Any

from weldpool_core.annotations.categories import pool_names
from weldpool_core.annotations.shapes import (
    DAMAGED,
    CocoPolygons,
    CocoRle,
    ImportedLabel,
    OtherShape,
    Parsed,
    Shape,
    check_vertices,
    text_or_none,
)
from weldpool_core.annotations.source import Source
from weldpool_core.errors import InvalidInputError

WELDPOOL_EXPORT = "weldpool reviewed labels"
"""``info.description`` of the COCO files weldpool exports."""
_SKIP_FOLDERS = ("keypoints/", "validation_keypoints/")


def coco_files(source: Source) -> list[str]:
    """The annotation files of a COCO import: the one named, else ``annotations.json``, else
    every JSON file under ``annotations/``, else every JSON file at the top."""
    if source.primary:
        return [source.primary]
    names = [n for n in source.names if n.lower().endswith(".json")]
    if "annotations.json" in names:
        return ["annotations.json"]
    nested = [n for n in names if n.startswith("annotations/")]
    return nested or [n for n in names if "/" not in n and not n.startswith(_SKIP_FOLDERS)]


def read_coco(source: Source, category: str | None = None) -> Parsed:
    parsed = Parsed()
    files = coco_files(source)
    if not files:
        raise InvalidInputError("No COCO annotation file (a JSON file) was found.")
    for name in files:
        try:
            document = source.read_json(name)
        except InvalidInputError as exc:
            parsed.refuse(name, exc.message)
            continue
        if not (
            isinstance(document, dict)
            and isinstance(document.get("images"), list)
            and isinstance(document.get("annotations"), list)
        ):
            parsed.refuse(name, "The file is not COCO: it needs `images` and `annotations` lists.")
            continue
        try:
            _read_document(document, name, category, parsed)
        except DAMAGED:
            parsed.refuse(name, "The file holds values of the wrong type or size.")
    return parsed


def _images(document: dict[str, Any], name: str, parsed: Parsed) -> dict[Any, dict[str, Any]]:
    images: dict[Any, dict[str, Any]] = {}
    for image in document["images"]:
        if not (
            isinstance(image, dict)
            and isinstance(image.get("file_name"), str)
            and _key(image.get("id")) is not None
        ):
            parsed.refuse(
                f"{name}: image {str(image)[:60]}", "An image needs an id and a file_name."
            )
            continue
        images[image["id"]] = image
    return images


def _key(value: Any) -> int | str | None:
    """An id as a dict key: ints and strings (a bool is not an id)."""
    return value if isinstance(value, int | str) and not isinstance(value, bool) else None


def _categories(document: dict[str, Any]) -> dict[Any, str]:
    categories = document.get("categories")
    return {
        c["id"]: str(c.get("name", c["id"]))
        for c in (categories if isinstance(categories, list) else [])
        if isinstance(c, dict) and _key(c.get("id")) is not None
    }


def _point_names(document: dict[str, Any]) -> dict[Any, list[str]]:
    """The ``keypoints`` names of each category that has them (a points class's)."""
    categories = document.get("categories")
    return {
        c["id"]: [str(n) for n in c["keypoints"]]
        for c in (categories if isinstance(categories, list) else [])
        if isinstance(c, dict)
        and _key(c.get("id")) is not None
        and isinstance(c.get("keypoints"), list)
    }


def _read_document(
    document: dict[str, Any], name: str, category: str | None, parsed: Parsed
) -> None:
    info = document.get("info")
    own = isinstance(info, dict) and info.get("description") == WELDPOOL_EXPORT
    images = _images(document, name, parsed)
    categories = _categories(document)
    point_names = _point_names(document)
    pool = pool_names(categories.values(), category)
    labels: dict[Any, ImportedLabel] = {}
    others: dict[Any, list[OtherShape]] = {}  # by image: regions of other categories
    refused: set[Any] = set()  # images whose label is refused whole (too many keypoints)
    for annotation in document["annotations"]:
        number = annotation.get("id", "?") if isinstance(annotation, dict) else "?"
        item = f"{name}: annotation {number}"
        if not isinstance(annotation, dict):
            parsed.refuse(item, "An annotation must be a JSON object.")
            continue
        image = images.get(_key(annotation.get("image_id")))
        if image is None:
            parsed.refuse(
                item,
                f"It names image {annotation.get('image_id')!r}, which the file does not list.",
            )
            continue
        category = annotation.get("category_id")
        category_name = categories.get(_key(category), category)
        if not isinstance(category_name, str) or category_name not in pool:
            names = point_names.get(_key(category), [])
            others.setdefault(image["id"], []).append(_other(str(category_name), annotation, names))
            continue
        try:
            shape = _shape(annotation.get("segmentation"))
            points = _keypoints(annotation.get("keypoints"))
            manual = _points(annotation.get("validation_keypoints")) if own else None
        except InvalidInputError as exc:
            parsed.refuse(item, exc.message)
            continue
        except DAMAGED:
            parsed.refuse(item, "It holds values of the wrong type or size.")
            continue
        if image["id"] in refused:
            continue
        label = labels.get(image["id"])
        if label is None:
            label = labels[image["id"]] = _label(image, name, own)
        if shape is not None:
            label.shapes.append(shape)
        if own:
            label.keypoints = points or label.keypoints
            label.validation_keypoints = manual or label.validation_keypoints
        elif points:  # several annotations' keypoints on one image: all of them
            try:
                label.add_keypoints(points, own=False)
            except InvalidInputError as exc:
                parsed.refuse(label.item, exc.message)
                refused.add(image["id"])
                del labels[image["id"]]
    for image_id, regions in others.items():
        parsed.attach(labels.get(image_id), regions)
    parsed.labels.extend(labels.values())


def _other(name: str, annotation: dict[str, Any], point_names: list[str]) -> OtherShape:
    """A region of another category (its shape None where it is not one COCO can state), or
    the named points of a category with ``keypoints`` names (those with v > 0)."""
    attributes = annotation.get("attributes")
    given = attributes if isinstance(attributes, dict) else {}
    other = OtherShape(name, attributes=given)
    try:
        flat = annotation.get("keypoints")
        if point_names and flat:
            if len(flat) != 3 * len(point_names):
                return other
            other.points = {
                point_names[i // 3]: [float(flat[i]), float(flat[i + 1])]
                for i in range(0, len(flat), 3)
                if _number(flat[i + 2])
                and flat[i + 2] > 0
                and _number(flat[i])
                and _number(flat[i + 1])
            } or None
        else:
            other.shape = _shape(annotation.get("segmentation"))
    except (InvalidInputError, *DAMAGED):
        pass
    return other


def _label(image: dict[str, Any], name: str, own: bool) -> ImportedLabel:
    height, width = image.get("height"), image.get("width")
    size = (height, width) if isinstance(height, int) and isinstance(width, int) else None
    label = ImportedLabel(
        item=f"{name}: {image['file_name']}", image=image["file_name"], size=size, beside=name
    )
    tags, attributes = image.get("tags"), image.get("attributes")
    if isinstance(tags, list):
        label.tags = [t for t in tags if isinstance(t, str)]
    if isinstance(attributes, dict):
        label.frame_attributes = attributes
    if own:
        label.sequence = text_or_none(image.get("sequence"))
        label.process = image.get("process") if isinstance(image.get("process"), dict) else None
        label.original_name = text_or_none(image.get("original_name"))
    else:
        label.original_name = posixpath.basename(image["file_name"])
    return label


def _shape(segmentation: Any) -> Shape | None:
    if segmentation is None or segmentation == []:
        return None
    if isinstance(segmentation, dict):
        size, counts = segmentation.get("size"), segmentation.get("counts")
        if not (
            isinstance(size, list)
            and len(size) == 2
            and all(isinstance(v, int) and v > 0 for v in size)
            and (
                isinstance(counts, str)
                or (isinstance(counts, list) and all(isinstance(c, int) for c in counts))
            )
        ):
            raise InvalidInputError("The RLE segmentation needs `size` [h, w] and `counts`.")
        return CocoRle({"size": size, "counts": counts})
    if isinstance(segmentation, list):
        for polygon in segmentation:
            check_vertices(len(polygon) // 2 if isinstance(polygon, list) else 0)
    if isinstance(segmentation, list) and all(
        isinstance(p, list) and len(p) >= 6 and len(p) % 2 == 0 and all(_number(v) for v in p)
        for p in segmentation
    ):
        return CocoPolygons(segmentation)
    raise InvalidInputError(
        "The segmentation is neither RLE nor polygons (lists of 3 or more x, y pairs)."
    )


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and value == value


def _keypoints(flat: Any) -> list[list[float]] | None:
    """COCO's ``[x1, y1, v1, …]``: the labelled ones (v > 0)."""
    if not flat:
        return None
    if not (isinstance(flat, list) and len(flat) % 3 == 0 and all(_number(v) for v in flat)):
        raise InvalidInputError("The keypoints are not a list of x, y, visibility triples.")
    points = [
        [float(flat[i]), float(flat[i + 1])] for i in range(0, len(flat), 3) if flat[i + 2] > 0
    ]
    return points or None


def _points(points: Any) -> list[list[float]] | None:
    if not points:
        return None
    if not (
        isinstance(points, list)
        and all(isinstance(p, list) and len(p) == 2 and all(_number(v) for v in p) for p in points)
    ):
        raise InvalidInputError("The validation keypoints are not a list of [x, y].")
    return [[float(x), float(y)] for x, y in points]
