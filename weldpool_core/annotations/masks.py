"""Mask folders: ``masks/<stem>.png`` (0/255 or 0/1) beside ``images/<stem>.<ext>``, the layout
``weldpool train`` reads and the ``masks`` export writes; ``keypoints/<stem>.json`` and
``validation_keypoints/<stem>.json`` (``{"keypoints": [[x, y], …]}``) and ``manifest.json``
(each frame's original name, run and process parameters; the other classes' objects, whose
masks are ``classes/<class>/<stem>[_<n>].png``; the frame's tags and attributes) are read when
present. A mask whose image is not in the source is matched to a stored frame by its stem."""

from __future__ import annotations

import posixpath
from typing import Any

from weldpool_core.annotations.shapes import (
    DAMAGED,
    ImportedLabel,
    MaskFile,
    OtherShape,
    Parsed,
    text_or_none,
)
from weldpool_core.annotations.source import Source
from weldpool_core.annotations.yolo import IMAGE_SUFFIXES
from weldpool_core.errors import InvalidInputError


def _manifest(source: Source, parsed: Parsed) -> dict[str, dict[str, Any]]:
    if "manifest.json" not in source:
        return {}
    try:
        frames = source.read_json("manifest.json").get("frames", [])
        return {str(f["stem"]): f for f in frames if isinstance(f, dict) and "stem" in f}
    except (*DAMAGED, InvalidInputError):
        parsed.refuse(
            "manifest.json", "The manifest is not valid JSON; names and runs are not read."
        )
        return {}


def _points(source: Source, path: str) -> list[list[float]] | None:
    if path not in source:
        return None
    try:
        document = source.read_json(path)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{path}: {exc.message}") from None
    if not isinstance(document, dict):
        raise InvalidInputError(f"{path} is not a keypoints file: it needs a `keypoints` list.")
    points = document.get("keypoints")
    if not points:
        return None
    if not all(isinstance(p, list) and len(p) == 2 for p in points):
        raise InvalidInputError(f"{path}'s keypoints are not a list of [x, y].")
    return [[float(x), float(y)] for x, y in points]


def _images_by_stem(source: Source) -> dict[str, str]:
    return {
        posixpath.splitext(n[len("images/") :])[0]: n
        for n in source.names
        if n.startswith("images/") and n.lower().endswith(IMAGE_SUFFIXES)
    }


def read_masks(source: Source, category: str | None = None) -> Parsed:
    del category  # a mask folder holds the pool only
    parsed = Parsed()
    manifest = _manifest(source, parsed)
    images = _images_by_stem(source)
    masks = [n for n in source.names if n.startswith("masks/") and n.lower().endswith(".png")]
    if not masks:
        raise InvalidInputError("No masks (masks/<stem>.png) were found.")
    for path in masks:
        stem = posixpath.splitext(path[len("masks/") :])[0]
        entry = manifest.get(stem, {})
        try:
            keypoints = _points(source, f"keypoints/{stem}.json")
            manual = _points(source, f"validation_keypoints/{stem}.json")
        except InvalidInputError as exc:
            parsed.refuse(path, exc.message)
            continue
        except (*DAMAGED, UnicodeDecodeError):
            parsed.refuse(path, "Its keypoints are not a list of [x, y] numbers.")
            continue
        image = images.get(stem)
        original = text_or_none(entry.get("original_name"))
        process = entry.get("process")
        label = ImportedLabel(
            item=path,
            image=posixpath.basename(image) if image else original or stem,
            shapes=[MaskFile(path)],
            keypoints=keypoints,
            validation_keypoints=manual,
            sequence=text_or_none(entry.get("sequence")),
            process=process if isinstance(process, dict) else None,
            original_name=original or (posixpath.basename(image) if image else None),
            beside=image or "",
        )
        try:
            _classes(source, entry, label)
        except DAMAGED:
            parsed.refuse(path, "Its manifest entry's objects, tags or attributes are damaged.")
            continue
        parsed.labels.append(label)
    return parsed


def _classes(source: Source, entry: dict[str, Any], label: ImportedLabel) -> None:
    """The label's other classes and frame fields as the manifest lists them: each object's
    class, ``mask`` (a PNG of the import) or ``points``, and ``attributes``; ``tags`` and
    ``attributes`` of the frame."""
    for item in entry.get("objects") or []:
        attributes = item.get("attributes")
        other = OtherShape(
            str(item["class"]), attributes=attributes if isinstance(attributes, dict) else {}
        )
        mask, points = item.get("mask"), item.get("points")
        if isinstance(mask, str) and mask in source:
            other.shape = MaskFile(mask)
        elif isinstance(points, dict):
            other.points = {str(n): [float(x), float(y)] for n, (x, y) in points.items()}
        label.others.append(other)
    tags, attributes = entry.get("tags"), entry.get("attributes")
    label.tags = [t for t in tags if isinstance(t, str)] if isinstance(tags, list) else []
    label.frame_attributes = attributes if isinstance(attributes, dict) else {}
