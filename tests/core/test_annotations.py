"""The label readers on damaged files: any value of any type anywhere gives refusals or labels,
and rasterising a label gives a mask or a one-sentence InvalidInputError, never another error
(which would end an import job with a traceback instead of a list of refusals)."""

from __future__ import annotations

import copy
import json
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from weldpool_core.annotations import READERS, Source
from weldpool_core.errors import InvalidInputError

H, W = 24, 32
ODD = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
    st.lists(st.integers(-5, 50), max_size=8),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=3),
)
COCO = {
    "info": {"description": "from another tool"},
    "images": [{"id": 1, "file_name": "a.png", "width": W, "height": H}],
    "annotations": [
        {
            "id": 1,
            "image_id": 1,
            "category_id": 1,
            "segmentation": [[1, 1, 20, 1, 20, 20]],
            "keypoints": [2, 2, 2, 5, 5, 1],
        },
        {
            "id": 2,
            "image_id": 1,
            "category_id": 1,
            "segmentation": {"size": [H, W], "counts": [10, 5, H * W - 15]},
        },
    ],
    "categories": [{"id": 1, "name": "weld_pool"}],
}
LABELME = {
    "shapes": [
        {"label": "weld_pool", "shape_type": "polygon", "points": [[1, 1], [20, 1], [20, 20]]},
        {"label": "weld_pool", "shape_type": "point", "points": [[3, 3]]},
        {"label": "weld_pool", "shape_type": "circle", "points": [[10, 10], [14, 10]]},
    ],
    "imagePath": "a.png",
    "imageHeight": H,
    "imageWidth": W,
}


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every place in a JSON document (dict keys, list indices)."""
    found = [prefix]
    if isinstance(value, dict):
        for key, item in value.items():
            found += _paths(item, (*prefix, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found += _paths(item, (*prefix, index))
    return found


def _replaced(document: dict, path: tuple, value: Any) -> Any:
    if not path:
        return value
    changed = copy.deepcopy(document)
    target = changed
    for step in path[:-1]:
        target = target[step]
    target[path[-1]] = value
    return changed


def _read_all(fmt: str, name: str, data: bytes) -> None:
    source = Source({name: lambda: data}, name, [], primary=name)
    parsed = READERS[fmt](source, None)
    for label in parsed.labels:
        try:
            mask = label.mask(H, W)
            label.checked_points(H, W)
            label.rasterised(H, W)
        except InvalidInputError as exc:
            assert exc.message.endswith((".", ")")), exc.message
            continue
        assert mask is None or mask.shape == (H, W)


def _mutations(document: dict) -> st.SearchStrategy:
    return st.tuples(st.sampled_from(_paths(document)), ODD)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(change=_mutations(COCO))
def test_a_damaged_coco_file_gives_refusals_never_another_error(change: tuple) -> None:
    path, value = change
    _read_all("coco", "a.json", json.dumps(_replaced(COCO, path, value)).encode())


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(change=_mutations(LABELME))
def test_a_damaged_labelme_file_gives_refusals_never_another_error(change: tuple) -> None:
    path, value = change
    _read_all("labelme", "a.json", json.dumps(_replaced(LABELME, path, value)).encode())


ATTRIBUTES = st.sampled_from(
    ["points", "rle", "left", "top", "width", "height", "label", "xtl", "ybr", "rotation"]
)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(
    attribute=ATTRIBUTES,
    value=st.one_of(
        st.text(alphabet="0123456789,;.-e ", max_size=12),
        st.sampled_from(["nan", "inf", "1e999", "0,10000000000"]),
    ),
    tag=st.sampled_from(["polygon", "mask", "points", "box", "polyline"]),
)
def test_a_damaged_cvat_file_gives_refusals_never_another_error(
    attribute: str, value: str, tag: str
) -> None:
    base = {
        "polygon": {"points": "1,1;20,1;20,20"},
        "mask": {"rle": "3, 4, 2", "left": "1", "top": "1", "width": "3", "height": "3"},
        "points": {"points": "3,3"},
        "box": {"xtl": "1", "ytl": "1", "xbr": "9", "ybr": "9"},
        "polyline": {"points": "1,1;2,2"},
    }[tag]
    attributes = base | {"label": "weld_pool", attribute: value}
    element = f"<{tag} " + " ".join(f'{k}="{v}"' for k, v in attributes.items()) + "/>"
    image = f'<image id="0" name="a.png" width="{W}" height="{H}">{element}</image>'
    xml = f"<annotations>{image}</annotations>"
    _read_all("cvat", "a.xml", xml.encode())


def test_the_undamaged_files_give_their_masks() -> None:
    """The fuzzed documents are good to begin with (else the tests above would prove little)."""
    for fmt, name, document in (("coco", "a.json", COCO), ("labelme", "a.json", LABELME)):
        data = json.dumps(document).encode()
        (label,) = READERS[fmt](
            Source({name: lambda d=data: d}, name, [], primary=name), None
        ).labels
        mask = label.mask(H, W)
        assert mask is not None and mask.sum() > 100 and np.asarray(label.validation_keypoints).size


def test_a_yolo_vertex_is_the_pixel_it_falls_in() -> None:
    """Squares from another tool at integer corners 10–20 and 11–21 stay one pixel apart (a
    half-pixel shift with round-half-even would fill both at 10–20), and our export's pixel
    centres read back exactly."""
    from weldpool_core.annotations.yolo import NormalisedPolygons

    def square(a: int, b: int) -> np.ndarray:
        xy = np.array([[a, a], [b, a], [b, b], [a, b]], np.float64) / np.array([W, H])
        return NormalisedPolygons([xy]).mask(H, W)

    left, right = square(10, 20), square(11, 21)
    assert np.flatnonzero(left.any(axis=0)).tolist() == list(range(10, 21))
    assert np.flatnonzero(right.any(axis=0)).tolist() == list(range(11, 22))
    centres = np.array([[3.5, 4.5], [9.5, 4.5], [9.5, 8.5], [3.5, 8.5]]) / np.array([W, H])
    exact = NormalisedPolygons([centres]).mask(H, W)
    assert exact[4:9, 3:10].all() and exact.sum() == 5 * 7


def test_a_damaged_zip_entry_is_one_sentence_and_too_many_keypoints_are_refused(
    tmp_path,
) -> None:
    import io
    import zipfile

    from weldpool_core.annotations import open_source
    from weldpool_core.annotations.shapes import ImportedLabel

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("images/a.png", b"x" * 5000)
    data = bytearray(buffer.getvalue())
    data[44:50] = b"\xff" * 6  # inside the deflate stream (the entry starts at byte 42)
    path = tmp_path / "damaged.zip"
    path.write_bytes(bytes(data))
    source = open_source(path)
    try:
        source.read("images/a.png")
    except InvalidInputError as exc:
        assert exc.message.startswith("The archive entry cannot be read")
    else:
        raise AssertionError("a damaged entry was read")
    finally:
        source.close()
    label = ImportedLabel("a", "a.png", validation_keypoints=[[1.0, 1.0]] * 65)
    try:
        label.checked_points(H, W)
    except InvalidInputError as exc:
        assert exc.message == "A label has at most 64 keypoints."
    else:
        raise AssertionError("65 keypoints were accepted")
