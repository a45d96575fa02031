"""CVAT for images 1.1 XML, both ways.

Read: each ``<image>``'s pool ``<polygon>``s, ``<box>``es, ``<mask>``s (CVAT's RLE over the box,
row by row, starting with a run of 0s) and ``<points>`` or CVAT 2 ``<skeleton>``s (keypoints:
the label's own when their ``kind`` attribute says ``label``, as our export writes them, else
placed by hand: validation keypoints). The XML is parsed by defusedxml (no entity expansion,
no external entities).

Other labels: a region of another label is an object (``OtherShape``); a ``<points>`` of
another label is a points object, its points named by its ``point_names`` attribute (else 1,
2, … in order); every shape's ``<attribute>``s are its object's attributes, as text. An
image's ``<tag>``s are its frame tags, and the ``<tag label="frame_attributes">``'s attributes
its frame attributes.

Write (``cvat_document``): one ``<mask>`` per label (so its holes survive), its keypoints and
its validation keypoints as ``<points>``; other labels' objects as ``<mask>`` or ``<points>``
with their ``<attribute>``s, the frame's tags as ``<tag>``s, every label and attribute declared
in the meta.
"""

from __future__ import annotations

import posixpath
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from defusedxml import DefusedXmlException
from defusedxml import ElementTree as SafeET

from weldpool_core.annotations.categories import pool_names
from weldpool_core.annotations.shapes import (
    DAMAGED,
    CocoPolygons,
    ImportedLabel,
    OtherShape,
    Parsed,
    PartialMask,
    Shape,
    check_vertices,
    cvat_rle,
    to_cvat_rle,
)
from weldpool_core.annotations.source import Source
from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

POOL_LABEL = "weld_pool"
KIND = "kind"  # the attribute telling a label's keypoints from validation keypoints
POINT_NAMES = "point_names"
"""The text attribute of a points object's ``<points>`` that names its points, in order
(``tip;root``)."""
FRAME_ATTRIBUTES = "frame_attributes"
"""The tag label whose ``<tag>`` carries a frame's attributes (CVAT has none of its own)."""


def cvat_files(source: Source) -> list[str]:
    if source.primary:
        return [source.primary]
    if "annotations.xml" in source:
        return ["annotations.xml"]
    return [n for n in source.names if n.lower().endswith(".xml")]


def read_cvat(source: Source, category: str | None = None) -> Parsed:
    parsed = Parsed()
    files = cvat_files(source)
    if not files:
        raise InvalidInputError("No CVAT annotation file (annotations.xml) was found.")
    for name in files:
        try:
            root = SafeET.fromstring(source.read(name))
        except DefusedXmlException:
            parsed.refuse(
                name, "The XML declares entities, which a CVAT file never does; it is not read."
            )
            continue
        except (ET.ParseError, ValueError) as exc:
            parsed.refuse(name, f"The file is not well-formed XML ({exc}).")
            continue
        if root.tag != "annotations":
            parsed.refuse(name, "The file is not CVAT for images XML (no <annotations> root).")
            continue
        declared = [e.text or "" for e in root.iterfind("./meta//labels/label/name")]
        used = [e.get("label", "") for e in root.iterfind("./image/*")]
        pool = pool_names(declared or used, category)
        for image in root.iterfind("image"):
            label = _image(name, image, pool, parsed)
            if label is not None:
                parsed.labels.append(label)
    return parsed


def _image(name: str, image: Any, pool: set[str], parsed: Parsed) -> ImportedLabel | None:
    file_name = image.get("name") or ""
    item = f"{name}: {file_name}"
    try:
        size = (int(image.get("height")), int(image.get("width")))
    except (TypeError, ValueError):
        size = None
    label = ImportedLabel(
        item=item,
        image=file_name,
        size=size,
        beside=name,
        original_name=posixpath.basename(file_name),
    )
    others: list[OtherShape] = []
    tags, frame_attributes = [], {}
    for element in image:
        if element.tag == "tag":
            if element.get("label") == FRAME_ATTRIBUTES:
                frame_attributes = _attributes(element)
            elif element.get("label"):
                tags.append(element.get("label"))
            continue
        if element.get("label") not in pool:
            others.append(_other(element))
            continue
        try:
            if element.tag in ("points", "skeleton"):
                points = [list(p) for p in _element_points(element)]
                label.add_keypoints(points, own=_attribute(element, KIND) == "label")
            else:
                label.shapes.append(_shape(element))
        except InvalidInputError as exc:
            parsed.refuse(f"{item} <{element.tag}>", exc.message)
            return None
        except DAMAGED:
            parsed.refuse(f"{item} <{element.tag}>", "Its attributes cannot be read as numbers.")
            return None
    kept = label if label.shapes or label.keypoints or label.validation_keypoints else None
    label.tags, label.frame_attributes = tags, frame_attributes
    parsed.attach(kept, others)
    return kept


def _other(element: Any) -> OtherShape:
    """A shape of another label with its attributes (as text): a region, or a ``<points>``'
    named points (named by its ``point_names`` attribute, else 1, 2, … in order); neither
    where it is another shape (polylines)."""
    attributes = _attributes(element)
    names = attributes.pop(POINT_NAMES, "").split(";")
    other = OtherShape(element.get("label") or "", attributes=attributes)
    try:
        if element.tag == "points":
            points = _points(element.get("points"))
            if len(names) != len(points) or len(set(names)) != len(names) or "" in names:
                names = [str(i) for i in range(1, len(points) + 1)]
            other.points = {n: [x, y] for n, (x, y) in zip(names, points, strict=True)}
        else:
            other.shape = _shape(element)
    except (InvalidInputError, *DAMAGED):
        pass
    return other


def _attributes(element: Any) -> dict[str, str]:
    """An element's ``<attribute name=…>`` children, as text."""
    return {
        a.get("name"): (a.text or "").strip()
        for a in element.iterfind("attribute")
        if a.get("name")
    }


def _element_points(element: Any) -> list[tuple[float, float]]:
    """A ``<points>``' points, or those of a CVAT 2 ``<skeleton>``: one ``<points>`` child per
    keypoint, in the skeleton's order (``outside="1"`` ones were not placed)."""
    if element.tag == "points":
        return _points(element.get("points"))
    return [
        point
        for child in element.iterfind("points")
        if child.get("outside", "0") != "1"
        for point in _points(child.get("points"))
    ]


def _attribute(element: Any, name: str) -> str | None:
    for attribute in element.iterfind("attribute"):
        if attribute.get("name") == name:
            return (attribute.text or "").strip()
    return None


def _points(text: str | None) -> list[tuple[float, float]]:
    check_vertices((text or "").count(";") + 1)  # counted before anything is split
    try:
        pairs = [pair.split(",") for pair in (text or "").split(";") if pair.strip()]
        points = [(float(x), float(y)) for x, y in pairs]
    except ValueError:
        raise InvalidInputError("The points are not 'x,y;x,y;…'.") from None
    if not points or not bool(np.isfinite(points).all()):
        raise InvalidInputError("The points are not 'x,y;x,y;…'.")
    return points


def _number(element: Any, name: str) -> float:
    try:
        return float(element.get(name))
    except (TypeError, ValueError):
        raise InvalidInputError(f"The <{element.tag}> has no number {name}.") from None


def _shape(element: Any) -> Shape:
    if element.tag == "polygon":
        points = _points(element.get("points"))
        if len(points) < 3:
            raise InvalidInputError("A polygon needs 3 or more points.")
        return CocoPolygons([[v for point in points for v in point]])  # CVAT: pixel corners
    if element.tag == "box":
        if _number(element, "rotation") if element.get("rotation") else 0.0:
            raise InvalidInputError("A rotated box cannot be imported as a pool.")
        x0, y0 = _number(element, "xtl"), _number(element, "ytl")
        x1, y1 = _number(element, "xbr"), _number(element, "ybr")
        return CocoPolygons([[x0, y0, x1, y0, x1, y1, x0, y1]])
    if element.tag == "mask":
        try:
            counts = [int(c) for c in (element.get("rle") or "").split(",") if c.strip()]
        except ValueError:
            raise InvalidInputError("The mask's rle is not comma-separated counts.") from None
        width, height = int(_number(element, "width")), int(_number(element, "height"))
        pixels = cvat_rle(counts, width, height)
        return PartialMask(pixels, int(_number(element, "left")), int(_number(element, "top")))
    raise InvalidInputError(f"A <{element.tag}> has no pool area to import.")


@dataclass(frozen=True)
class CvatMask:
    """A mask as CVAT writes it: the runs of its box's pixels (row-major, starting with 0s)
    and the box."""

    rle: str
    left: int
    top: int
    width: int
    height: int


def cvat_mask(mask: NDArray[np.bool_]) -> CvatMask | None:
    """The ``CvatMask`` of a frame's mask (None when it is empty)."""
    rows, columns = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not rows.size:
        return None
    top, bottom, left, right = (
        int(rows[0]),
        int(rows[-1]) + 1,
        int(columns[0]),
        int(columns[-1]) + 1,
    )
    return cvat_box_mask(mask[top:bottom, left:right], left, top)


def cvat_box_mask(pixels: NDArray[np.bool_], left: int, top: int) -> CvatMask:
    """The ``CvatMask`` of a box's pixels whose top-left is at (``left``, ``top``)."""
    height, width = pixels.shape
    return CvatMask(", ".join(map(str, to_cvat_rle(pixels))), left, top, width, height)


def cvat_rle_mask(rle: dict[str, Any], box: Sequence[float] | None) -> CvatMask | None:
    """The ``CvatMask`` of a compressed COCO RLE (as ``CocoMask`` holds it): laid out from its
    runs over its box ``[x, y, width, height]`` only, when the box is known (``rle_boxed``),
    else from the whole decoded mask (None when it is empty)."""
    from weldpool_core.outline import rle_boxed, rle_mask

    if box and box[2] > 0 and box[3] > 0:
        return cvat_box_mask(rle_boxed(rle, box).pixels, int(box[0]), int(box[1]))
    return cvat_mask(rle_mask(rle))


def cvat_rle_masks(
    stored: Sequence[tuple[dict[str, Any], Sequence[float] | None]],
) -> list[CvatMask | None]:
    """``cvat_rle_mask`` of several (RLE, box) pairs: one task of a process pool (an export's
    masks, a few per round trip)."""
    return [cvat_rle_mask(rle, box) for rle, box in stored]


@dataclass(frozen=True)
class CvatObject:
    """An object of another label: its mask, or its named points (in order), and its
    attributes as text."""

    label: str
    mask: CvatMask | None = None
    points: dict[str, list[float]] | None = None
    attributes: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class CvatAttribute:
    """An attribute a label declares in the meta: CVAT's ``input_type`` (select, checkbox,
    number, text) and ``values`` (a select's options; a number's min, max and step)."""

    name: str
    input_type: str
    values: Sequence[str] = ()
    default: str = ""


@dataclass(frozen=True)
class CvatLabel:
    """A label the meta declares besides the pool: its ``type`` (mask, points or tag) and
    attributes."""

    name: str
    type: str = "mask"
    attributes: Sequence[CvatAttribute] = ()


@dataclass(frozen=True)
class CvatImage:
    """One frame of a CVAT export: its file in the zip, size, mask and keypoints, the other
    labels' objects, the frame's tags and attributes (as text)."""

    id: int
    name: str
    width: int
    height: int
    mask: CvatMask | None
    keypoints: list[list[float]] | None
    validation_keypoints: list[list[float]] | None
    objects: list[CvatObject] = field(default_factory=list)
    tags: list[str] = field(default_factory=list)
    frame_attributes: dict[str, str] = field(default_factory=dict)


def _attribute_elements(parent: Any, attributes: dict[str, str]) -> None:
    for name, value in attributes.items():
        ET.SubElement(parent, "attribute", name=name).text = value


def _object_element(parent: Any, obj: CvatObject) -> None:
    if obj.mask is not None:
        element = _mask_element(parent, obj.label, obj.mask)
    elif obj.points:
        element = ET.SubElement(
            parent,
            "points",
            label=obj.label,
            source="manual",
            occluded="0",
            points=";".join(f"{x:.2f},{y:.2f}" for x, y in obj.points.values()),
            z_order="0",
        )
        ET.SubElement(element, "attribute", name=POINT_NAMES).text = ";".join(obj.points)
    else:
        return
    _attribute_elements(element, obj.attributes)


def _mask_element(parent: Any, label: str, mask: CvatMask) -> Any:
    return ET.SubElement(
        parent,
        "mask",
        label=label,
        source="manual",
        occluded="0",
        rle=mask.rle,
        left=str(mask.left),
        top=str(mask.top),
        width=str(mask.width),
        height=str(mask.height),
        z_order="0",
    )


def _points_element(parent: Any, points: list[list[float]], kind: str) -> None:
    element = ET.SubElement(
        parent,
        "points",
        label=POOL_LABEL,
        source="manual" if kind == "validation" else "auto",
        occluded="0",
        points=";".join(f"{x:.2f},{y:.2f}" for x, y in points),
        z_order="0",
    )
    ET.SubElement(element, "attribute", name=KIND).text = kind


def cvat_image(image: CvatImage) -> ET.Element:
    element = ET.Element(
        "image", id=str(image.id), name=image.name, width=str(image.width), height=str(image.height)
    )
    if image.mask is not None:
        _mask_element(element, POOL_LABEL, image.mask)
    for obj in image.objects:
        _object_element(element, obj)
    if image.keypoints:
        _points_element(element, image.keypoints, "label")
    if image.validation_keypoints:
        _points_element(element, image.validation_keypoints, "validation")
    for tag in image.tags:
        ET.SubElement(element, "tag", label=tag, source="manual")
    if image.frame_attributes:
        frame = ET.SubElement(element, "tag", label=FRAME_ATTRIBUTES, source="manual")
        _attribute_elements(frame, image.frame_attributes)
    return element


def cvat_document(
    images: Iterable[ET.Element], count: int, classes: Sequence[str | CvatLabel] = ()
) -> bytes:
    """The whole ``annotations.xml`` around already written ``<image>`` elements; the pool's
    label first, then ``classes`` (the other labels the images name: a bare name is a mask
    label without attributes)."""
    root = ET.Element("annotations")
    ET.SubElement(root, "version").text = "1.1"
    task = ET.SubElement(ET.SubElement(root, "meta"), "task")
    ET.SubElement(task, "name").text = "weldpool reviewed labels"
    ET.SubElement(task, "size").text = str(count)
    ET.SubElement(task, "mode").text = "annotation"
    label = ET.SubElement(ET.SubElement(task, "labels"), "label")
    ET.SubElement(label, "name").text = POOL_LABEL
    ET.SubElement(label, "type").text = "any"
    attribute = ET.SubElement(ET.SubElement(label, "attributes"), "attribute")
    ET.SubElement(attribute, "name").text = KIND
    ET.SubElement(attribute, "mutable").text = "False"
    ET.SubElement(attribute, "input_type").text = "select"
    ET.SubElement(attribute, "default_value").text = "validation"
    ET.SubElement(attribute, "values").text = "label\nvalidation"
    labels = task.find("labels")
    assert labels is not None  # made above
    for declared in classes:
        _label_element(labels, declared if isinstance(declared, CvatLabel) else CvatLabel(declared))
    root.extend(images)
    document: bytes = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return document


def _label_element(labels: Any, declared: CvatLabel) -> None:
    """A label of the meta with its attributes (a points label also its ``point_names``)."""
    other = ET.SubElement(labels, "label")
    ET.SubElement(other, "name").text = declared.name
    ET.SubElement(other, "type").text = declared.type
    attributes = ET.SubElement(other, "attributes")
    every = list(declared.attributes)
    if declared.type == "points":
        every.append(CvatAttribute(POINT_NAMES, "text"))
    for spec in every:
        attribute = ET.SubElement(attributes, "attribute")
        ET.SubElement(attribute, "name").text = spec.name
        ET.SubElement(attribute, "mutable").text = "False"
        ET.SubElement(attribute, "input_type").text = spec.input_type
        ET.SubElement(attribute, "default_value").text = spec.default
        ET.SubElement(attribute, "values").text = "\n".join(spec.values)
