"""An import keeps the pool whatever other classes a file has: regions of classes the label
configuration has become the label's objects, the others are counted in the result, and no
file is refused for a class it does not know."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from app.core.models import Role
from tests.helpers import auth, image_bytes
from tests.imports.common import H, W, label_mask, start_import, stored_labels, zipped
from weldpool_core.outline import rle_mask

CONFIG = {
    "version": 0,
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "wire tip", "kind": "points"},
    ],
}
SQUARE = "0.1 0.1 0.5 0.1 0.5 0.5 0.1 0.5"  # the pool, in 0–1 of the frame
WIRE = "0.6 0.6 0.9 0.6 0.9 0.9 0.6 0.9"


def _yolo(names: list[str], lines: dict[str, str]) -> bytes:
    files = {"data.yaml": ("names: " + json.dumps(names) + "\n").encode()}
    for i, (stem, text) in enumerate(lines.items()):
        files[f"images/train/{stem}.png"] = image_bytes(W, H, seed=40 + i)
        files[f"labels/train/{stem}.txt"] = text.encode()
    return zipped(files)


def _labels(client, token) -> dict[str, dict | None]:
    return {frame["original_name"]: label for frame, label in stored_labels(client, token)}


def _pool_of(label: dict) -> np.ndarray:
    return label_mask(label)


def test_a_yolo_file_with_wire_lines_keeps_every_pool(client, make_user) -> None:
    """Fifteen frames, two with a wire line besides the pool, one with a wire alone: without
    a configuration the fourteen pools come in and the wires are counted, by name."""
    _, token = make_user("lab", Role.annotator)
    lines = {f"f{i:02d}": f"0 {SQUARE}\n" for i in range(15)}
    lines["f03"] += f"1 {WIRE}\n"
    lines["f07"] = f"1 {WIRE}\n" + lines["f07"] + "2 0.1 0.7 0.2 0.7 0.2 0.9\n"
    lines["f14"] = f"1 {WIRE}\n"  # no pool on this frame
    result = start_import(client, token, _yolo(["weld_pool", "wire", "spatter"], lines), "yolo")[
        "result"
    ]
    assert result["refused"] == [] and result["labels"] == 14
    assert result["classes"]["unknown"] == {"spatter": 1, "wire": 2}
    assert result["classes"]["without_pool"] == {"wire": 1}
    assert {
        "item": "labels.zip",
        "reason": "Skipped 3 shape(s) of classes the label configuration does not have: "
        "wire ×2, spatter ×1.",
    } in result["skipped"]
    labels = _labels(client, token)
    pool = _pool_of(labels["f07.png"])
    assert pool[8:30, 11:46].all() and not pool[40:, 60:].any()  # the pool alone, not the wire
    assert labels["f07.png"]["objects"] == []


def test_configured_classes_come_in_as_objects(client, make_user) -> None:
    _, admin = make_user("ada", Role.admin)
    assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(admin)).status_code == 200
    lines = {
        "a": f"0 {SQUARE}\n1 {WIRE}\n1 0.6 0.1 0.9 0.1 0.9 0.3 0.6 0.3\n"
        "3 0.1 0.7 0.2 0.7 0.2 0.9 0.1 0.9\n3 0.3 0.7 0.4 0.7 0.4 0.9 0.3 0.9\n"
        "2 0.5 0.5 0.6 0.5 0.6 0.6\n4 0.5 0.5 0.6 0.5 0.6 0.6\n",
    }
    names = ["weld_pool", "filler", "tip", "spatter", "smoke"]
    data = _yolo(names, lines)
    result = start_import(client, admin, data, "yolo", class_map="filler=wire,tip=wire tip")[
        "result"
    ]
    assert result["classes"] == {
        "kept": {"spatter": 2, "wire": 2},
        "unknown": {"smoke": 1},
        "no_area": {},
        "no_points": {"wire tip": 1},  # a points class: a region is not its points
        "without_pool": {},
        "unknown_tags": {},
        "attributes_left_out": {},
    }
    label = _labels(client, admin)["a.png"]
    assert [o["class"] for o in label["objects"]] == ["wire", "spatter", "spatter"]
    wire = rle_mask(label["objects"][0]["rle"])
    assert wire[38:58, 57:87].all() and wire[6:20, 57:87].all()  # both wire lines: one mask
    assert wire.sum() == 30 * 20 + 30 * 14  # vertices are pixels, edges included
    first, second = (rle_mask(o["rle"]) for o in label["objects"][1:])
    assert first[44:58, 9:20].all() and first.sum() == 11 * 14  # each spatter its own
    assert second[44:58, 28:39].all() and second.sum() == 11 * 14
    assert label["objects"][1]["area"] == int(first.sum())
    pool = _pool_of(label)
    assert pool[8:30, 11:46].all() and not (pool & wire).any()  # the pool is the pool alone


@pytest.mark.parametrize("fmt", ["coco", "cvat", "labelme"])
def test_each_format_keeps_the_pool_beside_an_unknown_class(client, make_user, fmt) -> None:
    _, token = make_user("lab", Role.annotator)
    pool, other = [[10, 10], [40, 10], [40, 30], [10, 30]], [[60, 40], [80, 40], [80, 60]]
    if fmt == "coco":
        flat = [[v for p in pool for v in p]], [[v for p in other for v in p]]
        document = {
            "images": [{"id": 1, "file_name": "a.png", "width": W, "height": H}],
            "annotations": [
                {"id": 1, "image_id": 1, "category_id": 1, "segmentation": flat[0]},
                {"id": 2, "image_id": 1, "category_id": 2, "segmentation": flat[1]},
            ],
            "categories": [{"id": 1, "name": "weld_pool"}, {"id": 2, "name": "droplet"}],
        }
        files = {"annotations.json": json.dumps(document).encode()}
    elif fmt == "cvat":
        text = ";".join(f"{x},{y}" for x, y in pool), ";".join(f"{x},{y}" for x, y in other)
        xml = (
            f'<annotations><image id="0" name="a.png" width="{W}" height="{H}">'
            f'<polygon label="weld_pool" points="{text[0]}"/>'
            f'<polygon label="droplet" points="{text[1]}"/>'
            '<points label="droplet" points="3,3"/></image></annotations>'
        )
        files = {"annotations.xml": xml.encode()}
    else:
        shapes = [
            {"label": "weld_pool", "shape_type": "polygon", "points": pool},
            {"label": "droplet", "shape_type": "polygon", "points": other},
            {"label": "droplet", "shape_type": "point", "points": [[3, 3]]},
        ]
        document = {"shapes": shapes, "imagePath": "a.png", "imageHeight": H, "imageWidth": W}
        files = {"a.json": json.dumps(document).encode()}
    files["images/a.png" if fmt != "labelme" else "a.png"] = image_bytes(W, H, seed=5)
    result = start_import(client, token, zipped(files), fmt)["result"]
    assert result["refused"] == [] and result["labels"] == 1
    assert sum(result["classes"]["unknown"].values()) == (1 if fmt == "coco" else 2)
    label = _labels(client, token)["a.png"]
    assert label_mask(label)[12:28, 12:38].all() and not label_mask(label)[45:, 65:].any()


def test_the_command_line_maps_classes(tmp_path) -> None:
    """`weldpool import-labels --class-map`: the file's `filler` lines become `wire` objects of
    an instance configured with a wire class."""
    import sqlalchemy as sa
    from sqlalchemy.orm import Session

    from app.core.db import create_db_engine
    from app.core.models import Label, LabelConfig
    from app.core.schema import migrate
    from tests.helpers import run_cli

    folder, home = tmp_path / "yolo", tmp_path / "home"
    with zipfile.ZipFile(
        io.BytesIO(_yolo(["weld_pool", "filler"], {"a": f"0 {SQUARE}\n1 {WIRE}\n"}))
    ) as z:
        z.extractall(folder)
    home.mkdir()
    engine = create_db_engine(f"sqlite:///{home / 'weldpool.sqlite3'}")
    migrate(engine)
    with Session(engine) as session:
        session.add(
            LabelConfig(
                version=1,
                config={
                    "classes": [{"name": "pool", "kind": "mask"}, {"name": "wire", "kind": "mask"}]
                },
            )
        )
        session.commit()
    env = {"WELDPOOL_HOME": str(home)}
    added = run_cli(
        "user",
        "add",
        "admin",
        "--role",
        "admin",
        "--password-stdin",
        env=env,
        stdin="correct horse\n",
    )
    assert added.returncode == 0, added.stderr
    done = run_cli(
        "import-labels", folder, "--format", "yolo", "--class-map", "filler=wire", env=env
    )
    assert done.returncode == 0, done.stderr
    assert "1 labels and 0 keypoint sets imported" in done.stderr
    wrong = run_cli("import-labels", folder, "--format", "yolo", "--class-map", "filler", env=env)
    assert wrong.returncode != 0 and "is not file_name=our_name" in wrong.stderr
    with Session(engine) as session:
        objects = session.scalar(sa.select(Label.objects))
    engine.dispose()
    assert [o["class"] for o in objects] == ["wire"] and objects[0]["area"] == 30 * 20
