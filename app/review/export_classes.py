"""What an export writes beside the pool: each image's original file name (unique within the
export), and the label configuration's other classes with their objects, as COCO categories,
YOLO class ids and CVAT labels, points classes as COCO keypoint categories and CVAT ``<points>``,
attributes and frame tags where the format can hold them (``docs/guides/labels.md`` says which).
Objects of a class the configuration no longer has are left out (they stay on their labels).
What a format cannot carry is counted in the export's ``notes.txt``."""

from __future__ import annotations

import json
import posixpath
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy.orm import Session

from app.core.models import Frame
from app.labelconfig import service as labelconfig
from app.labelconfig.schemas import POOL
from weldpool_core.outline import rle_mask

if TYPE_CHECKING:
    from weldpool_core.annotations.cvat import CvatAttribute, CvatLabel, CvatObject

REGION_KINDS = ("mask", "instances")


class Rows(list[Any]):
    """An export's rows (frame, label, sequence, validation keypoints), with the label
    configuration in force: ``classes`` are its region classes (mask, instances) other than
    the pool, in its order; ``points`` its points classes, each with the names of its points
    (the class's own, else those the rows' objects use, in the order first met)."""

    def __init__(
        self, rows: list[Any], classes: Sequence[str] = (), config: dict[str, Any] | None = None
    ) -> None:
        super().__init__(rows)
        bare = [{"name": name, "kind": "instances"} for name in classes]  # without a config
        self.config = config or {"classes": bare}
        specs = [c for c in self.config["classes"] if c["name"] != POOL]
        self.classes = [c["name"] for c in specs if c["kind"] in REGION_KINDS]
        self.specs = {c["name"]: c for c in specs}
        self.points = {
            c["name"]: list(c.get("point_names") or []) for c in specs if c["kind"] == "points"
        }
        for row in rows:
            for obj in row[1].objects or []:
                names = self.points.get(obj.get("class"))
                if names is not None and not self.specs[obj["class"]].get("point_names"):
                    names += [n for n in obj.get("points", {}) if n not in names]


def written_classes(rows: list[Any]) -> list[str]:
    """The configured classes an export writes besides the pool (none for plain rows)."""
    return rows.classes if isinstance(rows, Rows) else []


def written_config(rows: list[Any]) -> Rows:
    """The rows as ``Rows`` (plain rows: with no configuration, the pool alone)."""
    return rows if isinstance(rows, Rows) else Rows(rows)


def configured_rows(session: Session, rows: list[Any]) -> Rows:
    """``rows`` with the label configuration in force."""
    return Rows(rows, config=labelconfig.current(session).config)


def file_names(frames: list[Frame]) -> dict[int, str]:
    """Each frame's original file name (its base name, with the stored file's extension when
    the name has another), unique within the export by stem, ignoring case (a YOLO label
    file is named by its image's stem): in frame id order the first keeps its name, a later
    one gets ``<stem>-<frame id>``; a frame without a name is named by its id."""
    names: dict[int, str] = {}
    taken: set[str] = set()
    for frame in sorted(frames, key=lambda f: f.id):
        suffix = Path(frame.path).suffix
        base = posixpath.basename((frame.original_name or "").replace("\\", "/")).strip()
        stem, ext = posixpath.splitext(base)
        if not stem or stem.startswith("."):
            stem, ext = f"{frame.id:07d}", suffix
        elif ext.lower() != suffix.lower():
            stem, ext = base, suffix
        candidate, extra = stem, 0
        while candidate.casefold() in taken:
            extra += 1
            candidate = f"{stem}-{frame.id}" + (f"-{extra}" if extra > 1 else "")
        taken.add(candidate.casefold())
        names[frame.id] = candidate + ext
    return names


def exported_objects(label: Any, classes: list[str]) -> list[dict[str, Any]]:
    """The label's objects of ``classes`` that have a region, in the label's order."""
    return [o for o in label.objects or [] if o.get("class") in classes and o.get("rle")]


def yaml_name(name: str) -> str:
    """A class name as a YAML value: as it is when it is a plain word, else JSON-quoted (a
    JSON string is a YAML string: a name like ``on`` or ``1`` stays a name)."""
    plain = name.replace("_", "").isalnum() and name.isascii() and not name[0].isdigit()
    return name if plain and name.lower() not in YAML_WORDS else json.dumps(name)


YAML_WORDS = {"y", "n", "yes", "no", "on", "off", "true", "false", "null"}


def yolo_lines(label: Any, classes: list[str], height: int, width: int) -> list[str]:
    """One line per region of each object: its class id (the pool is 0, the classes follow)
    and its outline, 0–1 of the frame."""
    from weldpool_core.outline import normalised, region_outlines

    lines = []
    for obj in exported_objects(label, classes):
        class_id = classes.index(obj["class"]) + 1
        for points in region_outlines(rle_mask(obj["rle"])):
            values = normalised(points, height, width)
            lines.append(f"{class_id} " + " ".join(f"{v:.6f}" for v in values))
    return lines


def frame_fields(label: Any) -> dict[str, Any]:
    """A label's frame tags and attributes (empty when it has none)."""
    held = label.frame_tags or {}
    return {"tags": list(held.get("tags", [])), "attributes": dict(held.get("attributes", {}))}


def _written(label: Any, rows: Rows) -> list[dict[str, Any]]:
    """The label's objects an export writes: of a configured region class with a region, or
    of a configured points class with points; in the label's order."""
    return [
        o
        for o in label.objects or []
        if (o.get("class") in rows.classes and o.get("rle"))
        or (o.get("class") in rows.points and o.get("points"))
    ]


def coco_categories(rows: Rows) -> list[dict[str, Any]]:
    """The categories after the pool's (id 1): the region classes (2 on), then each points
    class with its points' names as ``keypoints``."""
    regions = [{"name": name, "supercategory": "weld"} for name in rows.classes]
    points = [
        {"name": name, "supercategory": "weld", "keypoints": names, "skeleton": []}
        for name, names in rows.points.items()
    ]
    return [c | {"id": i + 2} for i, c in enumerate(regions + points)]


def coco_objects(label: Any, rows: Rows, image_id: int) -> list[dict[str, Any]]:
    """COCO annotations of the label's objects (ids given by the writer), as
    ``coco_categories`` numbers them: a region as RLE, a points object as keypoints
    ``[x, y, v]`` in its category's order (v 2: placed, 0: not), with the box of its points."""
    ids = {c["name"]: c["id"] for c in coco_categories(rows)}
    made = []
    for obj in _written(label, rows):
        base = {"image_id": image_id, "category_id": ids[obj["class"]], "iscrowd": 0}
        base["attributes"] = obj.get("attributes", {})
        if obj.get("rle"):
            made.append(
                base | {"segmentation": obj["rle"], "area": obj["area"], "bbox": obj["bbox"]}
            )
            continue
        points = obj["points"]
        flat: list[float] = []
        for name in rows.points[obj["class"]]:
            flat += [*map(float, points[name]), 2] if name in points else [0.0, 0.0, 0]
        xs, ys = [p[0] for p in points.values()], [p[1] for p in points.values()]
        box = [min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)]
        made.append(
            base
            | {"segmentation": [], "area": box[2] * box[3], "bbox": box, "keypoints": flat}
            | {"num_keypoints": len(points)}
        )
    return made


def cvat_objects(label: Any, rows: Rows) -> list[CvatObject]:
    """The label's objects as CVAT writes them: a region as a mask (box pixels only, laid out
    from its stored RLE over its box), a points object as its named points; with their
    attributes as text. In the export's pool, beside the pool's mask."""
    from weldpool_core.annotations.cvat import CvatObject, cvat_rle_mask

    made = []
    for obj in _written(label, rows):
        attributes = {k: cvat_text(v) for k, v in obj.get("attributes", {}).items()}
        if obj.get("points"):
            made.append(CvatObject(obj["class"], points=obj["points"], attributes=attributes))
            continue
        mask = cvat_rle_mask(obj["rle"], obj.get("bbox"))
        if mask is not None:
            made.append(CvatObject(obj["class"], mask=mask, attributes=attributes))
    return made


def cvat_text(value: Any) -> str:
    """An attribute's value as CVAT writes it: a flag ``true``/``false``, a number or text."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def cvat_labels(rows: Rows) -> list[CvatLabel]:
    """The labels the CVAT meta declares after the pool: each configured class (mask or points)
    with its attributes, each frame tag (a tag label), and the frame's attributes on the tag
    label ``frame_attributes`` when the configuration has any."""
    from weldpool_core.annotations.cvat import FRAME_ATTRIBUTES, CvatLabel

    labels = [
        CvatLabel(name, "points" if name in rows.points else "mask", _cvat_attributes(spec))
        for name, spec in rows.specs.items()
        if name in rows.classes or name in rows.points
    ]
    labels += [CvatLabel(tag, "tag") for tag in rows.config.get("frame_tags", [])]
    if specs := rows.config.get("frame_attributes"):
        labels.append(CvatLabel(FRAME_ATTRIBUTES, "tag", _cvat_attributes({"attributes": specs})))
    return labels


def _cvat_attributes(spec: dict[str, Any]) -> list[CvatAttribute]:
    """A class's attributes as CVAT declares them: choice a select, flag a checkbox, number a
    number (min, max, step 1) when it has both bounds, else text, as text is."""
    from weldpool_core.annotations.cvat import CvatAttribute

    made = []
    for a in spec.get("attributes", []):
        if a["type"] == "choice":
            made.append(CvatAttribute(a["name"], "select", a["options"], a["options"][0]))
        elif a["type"] == "flag":
            made.append(CvatAttribute(a["name"], "checkbox", ["false"], "false"))
        elif a["type"] == "number" and a.get("min") is not None and a.get("max") is not None:
            bounds = [f"{a['min']:g}", f"{a['max']:g}", "1"]
            made.append(CvatAttribute(a["name"], "number", bounds, bounds[0]))
        else:
            made.append(CvatAttribute(a["name"], "text"))
    return made


def yolo_notes(rows: Rows) -> str:
    """What a YOLO export leaves out, counted (YOLO segmentation holds class ids and polygons
    alone): points objects, attributes of objects, frame tags and attributes; "" for none."""
    points = attributes = tagged = 0
    for row in rows:
        label = row[1]
        for obj in _written(label, rows):
            points += obj["class"] in rows.points
            attributes += bool(obj.get("attributes"))
        held = label.frame_tags or {}
        tagged += bool(held.get("tags") or held.get("attributes"))
    lines = [
        f"{count} {what} left out: {why}\n"
        for count, what, why in (
            (points, "points object(s)", "YOLO segmentation has no named points"),
            (attributes, "object(s) with attributes", "their attributes are not written"),
            (tagged, "frame(s) with tags or attributes", "YOLO has no frame tags"),
        )
        if count
    ]
    return "".join(lines)


def manifest_classes(rows: Rows) -> list[dict[str, Any]]:
    """The classes the masks export writes beside the pool, as its ``manifest.json`` declares
    them for ``weldpool train --classes``: name, kind and a points class's ``point_names``."""
    regions = [{"name": n, "kind": rows.specs[n]["kind"]} for n in rows.classes]
    points = [{"name": n, "kind": "points", "point_names": p} for n, p in rows.points.items()]
    return regions + points


@dataclass
class ClassFiles:
    """What the masks export writes of a label's objects: a PNG (0/255) per region object,
    ``classes/<class>/<stem>.png`` for a mask class's and ``classes/<class>/<stem>_<n>.png``
    for an instances class's n-th; and the manifest's ``objects`` (each with its ``mask`` file
    or its ``points``, and its ``attributes``), in the label's order."""

    files: list[tuple[str, bytes]] = field(default_factory=list)
    objects: list[dict[str, Any]] = field(default_factory=list)


def class_files(label: Any, rows: Rows, stem: str) -> ClassFiles:
    from weldpool_core.io import encode_mask_png

    made, counts = ClassFiles(), Counter[str]()
    for obj in _written(label, rows):
        name = obj["class"]
        entry: dict[str, Any] = {"class": name, "attributes": obj.get("attributes", {})}
        if obj.get("points"):
            made.objects.append(entry | {"points": obj["points"]})
            continue
        counts[name] += 1
        folder = name.replace("/", "_").replace("\\", "_")
        number = f"_{counts[name]}" if rows.specs[name]["kind"] == "instances" else ""
        path = f"classes/{folder}/{stem}{number}.png"
        made.files.append((path, encode_mask_png(rle_mask(obj["rle"]))))
        made.objects.append(entry | {"mask": path})
    return made
