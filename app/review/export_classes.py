"""What an export writes beside the pool: each image's original file name (unique within the
export), and the label configuration's other classes with their objects, as COCO categories,
YOLO class ids and CVAT labels. Objects of a class the configuration no longer has are left
out (they stay on their labels); ``points`` classes are not written yet."""

from __future__ import annotations

import json
import posixpath
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy.orm import Session

from app.core.models import Frame
from app.labelconfig import service as labelconfig
from app.labelconfig.schemas import POOL
from weldpool_core.outline import rle_mask

if TYPE_CHECKING:
    from weldpool_core.annotations.cvat import CvatMask

REGION_KINDS = ("mask", "instances")


class Rows(list[Any]):
    """An export's rows (frame, label, sequence, validation keypoints), with the configured
    classes other than the pool whose objects it writes, in the configuration's order."""

    def __init__(self, rows: list[Any], classes: list[str]) -> None:
        super().__init__(rows)
        self.classes = classes


def written_classes(rows: list[Any]) -> list[str]:
    """The configured classes an export writes besides the pool (none for plain rows)."""
    return rows.classes if isinstance(rows, Rows) else []


def region_classes(session: Session) -> list[str]:
    """The configured classes whose objects are regions (mask, instances), pool aside."""
    return [
        c["name"]
        for c in labelconfig.current(session).config["classes"]
        if c["name"] != POOL and c["kind"] in REGION_KINDS
    ]


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


def coco_objects(label: Any, classes: list[str], image_id: int) -> list[dict[str, Any]]:
    """COCO annotations of the label's objects (ids given by the writer): category id 2 on."""
    return [
        {
            "image_id": image_id,
            "category_id": classes.index(obj["class"]) + 2,
            "iscrowd": 0,
            "segmentation": obj["rle"],
            "area": obj["area"],
            "bbox": obj["bbox"],
            "attributes": obj.get("attributes", {}),
        }
        for obj in exported_objects(label, classes)
    ]


def cvat_objects(label: Any, classes: list[str]) -> list[tuple[str, CvatMask]]:
    """The label's objects as CVAT masks (box pixels only, laid out from each one's stored RLE
    over its box), with their class names; in the export's pool, beside the pool's mask."""
    from weldpool_core.annotations.cvat import cvat_rle_mask

    made = []
    for obj in exported_objects(label, classes):
        mask = cvat_rle_mask(obj["rle"], obj.get("bbox"))
        if mask is not None:
            made.append((obj["class"], mask))
    return made
