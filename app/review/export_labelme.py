"""The LabelMe export: ``images/<name>`` and ``images/<stem>.json`` beside it, as LabelMe opens
a folder (images by their original names, unique within the export). The pool is a ``mask``
shape (its holes kept), its keypoints ``point`` shapes (``description`` ``label``; validation
keypoints without one); a region object a ``mask`` shape of its class, a points object one
``point`` shape per named point (``description``: the point's name; ``group_id``: the object);
an object's flag attributes its shape's ``flags``, its other attributes the shape's
``attributes`` (an extra key LabelMe keeps). The frame's tags are the file's ``flags`` (every
configured tag, true where the frame has it), its attributes the file's ``attributes``."""

from __future__ import annotations

import json
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.review.export_classes import Rows, file_names, frame_fields, written_config
from weldpool_core.annotations.labelme import (
    LABEL_KEYPOINT,
    labelme_document,
    labelme_mask,
    labelme_point,
)
from weldpool_core.outline import BoxedMask, rle_boxed

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray


def _boxed(mask: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], int, int] | None:
    boxed = BoxedMask.of(mask)
    return None if boxed.empty else (boxed.pixels, *boxed.origin)


def _with_attributes(shape: dict[str, Any], attributes: dict[str, Any]) -> dict[str, Any]:
    flags = {k: v for k, v in attributes.items() if isinstance(v, bool)}
    others = {k: v for k, v in attributes.items() if not isinstance(v, bool)}
    return shape | {"flags": flags} | ({"attributes": others} if others else {})


def object_shapes(label: Any, rows: Rows) -> list[dict[str, Any]]:
    """The label's objects of the configured classes as LabelMe shapes, in the label's order."""
    shapes: list[dict[str, Any]] = []
    group = 0
    for obj in label.objects or []:
        name, attributes = obj.get("class"), obj.get("attributes", {})
        if name in rows.classes and obj.get("rle") and obj.get("bbox"):
            x, y = int(obj["bbox"][0]), int(obj["bbox"][1])
            pixels = rle_boxed(obj["rle"], [int(v) for v in obj["bbox"]]).pixels
            shapes.append(_with_attributes(labelme_mask(name, pixels, x, y), attributes))
        elif name in rows.points and obj.get("points"):
            group += 1
            for point, xy in obj["points"].items():
                shape = labelme_point(name, xy, point) | {"group_id": group}
                shapes.append(_with_attributes(shape, attributes))
    return shapes


def labelme_file(
    frame: Any, label: Any, manual: Any, name: str, pool: NDArray[np.bool_], rows: Rows
) -> bytes:
    """One frame's LabelMe JSON."""
    shapes = []
    if (boxed := _boxed(pool)) is not None:
        shapes.append(labelme_mask("weld_pool", *boxed))
    shapes += [labelme_point("weld_pool", xy, LABEL_KEYPOINT) for xy in label.keypoints or []]
    shapes += [labelme_point("weld_pool", xy) for xy in (manual.keypoints if manual else [])]
    shapes += object_shapes(label, rows)
    fields = frame_fields(label)
    flags = {tag: tag in fields["tags"] for tag in rows.config.get("frame_tags", [])}
    document = labelme_document(name, frame.height, frame.width, shapes, flags)
    if fields["attributes"]:
        document["attributes"] = fields["attributes"]
    return json.dumps(document, indent=1).encode()


def write_labelme(
    archive: zipfile.ZipFile,
    rows: list[Any],
    readable: Callable[[Callable[[Any], Any]], Iterator[tuple[int, Any, Path | None, Any]]],
    pool_mask: Callable[[Any], NDArray[np.bool_]],
) -> Iterator[int]:
    """Each row's image and LabelMe file (``readable``: the export's rows with their images
    and ``read``'s result, fetched ahead; ``pool_mask``: a label's mask)."""
    config = written_config(rows)
    names = file_names([row[0] for row in rows])

    def made(row: Any) -> bytes:  # in the readers' pool
        frame, label, _, manual = row
        return labelme_file(frame, label, manual, names[frame.id], pool_mask(label), config)

    for done, (frame, _, _, _), image, document in readable(made):
        if image is not None:
            name = names[frame.id]
            archive.write(image, f"images/{name}")
            archive.writestr(f"images/{Path(name).stem}.json", document)
        yield done
