"""An import's parsing is bounded by what it produces, not by what a file tells it: YAML aliases,
over-compressed archives, huge polygons, endless keypoints and many tiny shapes each cost what
a real file of their size costs, or are refused with one sentence before they are read."""

from __future__ import annotations

import base64
import io
import json
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest

from weldpool_core.annotations import open_source
from weldpool_core.annotations import shapes as shapes_module
from weldpool_core.annotations.coco import read_coco
from weldpool_core.annotations.cvat import read_cvat
from weldpool_core.annotations.labelme import read_labelme
from weldpool_core.annotations.masks import read_masks
from weldpool_core.annotations.shapes import MAX_POLYGON_VERTICES, Polygons
from weldpool_core.annotations.yolo import read_yolo
from weldpool_core.errors import InvalidInputError
from weldpool_core.outline import Polygon, fill_polygons

MiB = 1024 * 1024


def _zip(path: Path, files: list[tuple[str, bytes]]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files:
            archive.writestr(name, data)
    return path


def test_a_yaml_alias_bomb_in_data_yaml_is_refused_with_one_sentence(tmp_path: Path) -> None:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for level in range(1, 9):
        previous = f"*a{level - 1}"
        lines.append(f"a{level}: &a{level} [{', '.join([previous] * 9)}]")
    lines.append("names: *a8")
    (tmp_path / "data.yaml").write_text("\n".join(lines))
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "f.txt").write_text("0 0.1 0.1 0.5 0.1 0.5 0.5\n")
    with pytest.raises(InvalidInputError, match="aliases") as refused:
        read_yolo(open_source(tmp_path), None)
    assert refused.value.message.endswith(".") and "data.yaml" in refused.value.message


def test_an_archive_of_small_over_compressed_entries_is_refused_before_it_is_read(
    tmp_path: Path,
) -> None:
    zeros = bytes(MiB)  # each entry 1 MiB: under the per-entry ratio rule's 1 MiB floor
    path = _zip(tmp_path / "bomb.zip", [(f"masks/{i}.png", zeros) for i in range(100)])
    assert path.stat().st_size < 2 * MiB
    with pytest.raises(InvalidInputError, match="expand to") as refused:
        open_source(path)
    assert "zip bomb" in refused.value.message


def test_reading_masks_holds_no_mask_file_until_its_batch(tmp_path: Path) -> None:
    noise = np.random.default_rng(0).integers(0, 255, 256 * 1024, np.uint8).tobytes()
    path = _zip(tmp_path / "masks.zip", [(f"masks/{i}.png", noise) for i in range(80)])
    source = open_source(path)
    tracemalloc.start()
    parsed = read_masks(source, None)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(parsed.labels) == 80
    assert peak < 4 * MiB  # 80 × 256 KiB were all held before


def test_reading_labelme_holds_no_embedded_image_until_its_batch(tmp_path: Path) -> None:
    image = base64.b64encode(bytes(512 * 1024)).decode()
    shape = {"label": "pool", "shape_type": "polygon", "points": [[1, 1], [9, 1], [9, 9]]}
    for i in range(40):
        document = {"shapes": [shape], "imagePath": f"{i}.png", "imageData": image}
        (tmp_path / f"{i}.json").write_text(json.dumps(document))
    source = open_source(tmp_path)
    tracemalloc.start()
    parsed = read_labelme(source, None)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(parsed.labels) == 40
    assert peak < 8 * MiB  # 40 documents and their 40 decoded images were all held before
    assert parsed.labels[0].loaded(source).image_data == bytes(512 * 1024)


def test_a_cvat_polygon_of_too_many_points_is_refused_with_one_sentence(tmp_path: Path) -> None:
    points = ";".join(f"{i % 50}.0,{i % 40}.0" for i in range(MAX_POLYGON_VERTICES + 1))
    xml = (
        '<annotations><image id="0" name="f.png" width="64" height="48">'
        f'<polygon label="pool" points="{points}"/></image></annotations>'
    )
    (tmp_path / "annotations.xml").write_text(xml)
    parsed = read_cvat(open_source(tmp_path), None)
    assert parsed.labels == []
    [refusal] = parsed.refused
    assert f"{MAX_POLYGON_VERTICES:,} vertices" in refusal.reason


def test_many_keypoint_annotations_on_one_image_are_refused_as_the_reader_meets_them(
    tmp_path: Path,
) -> None:
    document = {
        "images": [{"id": 1, "file_name": "f.png", "width": 64, "height": 48}],
        "categories": [{"id": 1, "name": "pool"}],
        "annotations": [
            {"id": i, "image_id": 1, "category_id": 1, "keypoints": [5, 5, 2]} for i in range(500)
        ],
    }
    (tmp_path / "annotations.json").write_text(json.dumps(document))
    parsed = read_coco(open_source(tmp_path), None)
    assert parsed.labels == []
    assert [r.item for r in parsed.refused] == ["annotations.json: f.png"]
    assert "at most 64 keypoints" in parsed.refused[0].reason


@pytest.mark.parametrize("count", [5, 400])  # filled one by one; grouped where apart
def test_many_tiny_polygons_cost_their_boxes_not_a_frame_each(monkeypatch, count: int) -> None:
    height, width = 400, 600
    corners = [(x, y) for x in range(-1, width - 4, 23) for y in range(-1, height - 4, 19)]
    polygons = [
        Polygon([(x, y), (x + 3.5, y), (x + 3, y + 2.5), (x, y + 3)]) for x, y in corners[:count]
    ]
    polygons += [Polygon([(50, 50), (60, 52), (55, 58)]), Polygon([(52, 49), (70, 60), (51, 61)])]
    polygons.append(Polygon([(width - 2, 100), (width + 0.9, 100), (width, 110)]))  # on the edge
    expected = np.zeros((height, width), bool)
    for polygon in polygons:
        expected |= fill_polygons([polygon], height, width)
    canvases: list[tuple[int, int]] = []

    def fill(polygons, h, w):  # type: ignore[no-untyped-def]
        canvases.append((h, w))
        return fill_polygons(polygons, h, w)

    monkeypatch.setattr(shapes_module, "fill_polygons", fill)
    mask = Polygons(polygons).mask(height, width)
    assert np.array_equal(mask, expected)
    assert sum(h * w for h, w in canvases) <= height * width  # was a whole frame per polygon


def test_an_archive_with_two_entries_of_one_name_reads_neither(tmp_path: Path) -> None:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("masks/a.png", b"one")
        with pytest.warns(UserWarning):
            archive.writestr("masks/a.png", b"two")
        archive.writestr("masks/b.png", b"three")
    path = tmp_path / "twice.zip"
    path.write_bytes(buffer.getvalue())
    source = open_source(path)
    assert source.names == ["masks/b.png"]
    [refusal] = source.refused
    assert refusal.item == "masks/a.png" and "2 entries" in refusal.reason


def test_many_coco_polygons_make_the_union_of_each_ones_mask() -> None:
    from weldpool_core.annotations.shapes import CocoPolygons

    height, width = 60, 80
    squares = [
        [x, y, x + 6.0, y, x + 6.0, y + 5.0, x, y + 5.0]
        for x, y in ((2, 3), (5, 6), (40, 9), (60, 40), (61, 42))
    ]
    expected = np.zeros((height, width), bool)
    for square in squares:
        expected |= CocoPolygons([square]).mask(height, width)
    assert np.array_equal(CocoPolygons(squares).mask(height, width), expected)
