"""A DATASET folder's other classes (``student.folder.read_classes``): the masks export's layout
read back as each frame's class labels, and one clear sentence for what it cannot read."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.core.student.common import TINY_STUDENT, tiny_config
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import encode_mask_png
from weldpool_core.student.checkpoint import read_student_config
from weldpool_core.student.classes import LearnedClass
from weldpool_core.student.folder import read_classes, train_from_folder

H, W = 32, 48


def _box(top: int, left: int, size: int = 6) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[top : top + size, left : left + size] = True
    return mask


def _dataset(root: Path, manifest: dict | None = None) -> Path:
    """Three frames a, b, c; the wire on a and b, two spatter instances on a, the tip on a and c."""
    for part in ("images", "masks", "classes/wire", "classes/spatter"):
        (root / part).mkdir(parents=True)
    for stem in "abc":
        cv2.imwrite(str(root / "images" / f"{stem}.png"), np.zeros((H, W, 3), np.uint8))
        (root / "masks" / f"{stem}.png").write_bytes(encode_mask_png(_box(10, 10, 12)))
    (root / "classes/wire/a.png").write_bytes(encode_mask_png(_box(0, 0)))
    (root / "classes/wire/b.png").write_bytes(encode_mask_png(_box(0, 20)))
    (root / "classes/spatter/a_1.png").write_bytes(encode_mask_png(_box(20, 0)))
    (root / "classes/spatter/a_2.png").write_bytes(encode_mask_png(_box(20, 30)))
    frames = [
        {"stem": "a", "objects": [{"class": "tip", "points": {"end": [4.0, 5.0]}}]},
        {"stem": "c", "objects": [{"class": "tip", "points": {"end": [7.5, 1.0], "root": [1, 2]}}]},
    ]
    (root / "manifest.json").write_text(json.dumps(manifest or {"frames": frames}))
    return root


def test_the_export_layout_gives_each_frame_its_class_labels(tmp_path: Path) -> None:
    learned, frames = read_classes(_dataset(tmp_path), ["wire", "spatter", "tip"])
    assert learned == (
        LearnedClass("wire", "mask"),
        LearnedClass("spatter", "instances"),  # numbered files
        LearnedClass("tip", "points", ("end", "root")),
    )
    a, b, c = frames
    assert np.array_equal(a.classes["wire"].mask, _box(0, 0))
    assert np.array_equal(b.classes["wire"].mask, _box(0, 20))  # each frame its own file
    assert np.array_equal(a.classes["spatter"].mask, _box(20, 0) | _box(20, 30))  # the union
    assert dict(a.classes["tip"].points) == {"end": (4.0, 5.0)}
    assert dict(c.classes["tip"].points) == {"end": (7.5, 1.0), "root": (1.0, 2.0)}
    assert set(b.classes) == {"wire"} and set(c.classes) == {"tip"}  # unlabelled: no truth
    assert np.array_equal(a.mask, _box(10, 10, 12))  # the pool as before


def test_the_manifests_declaration_gives_kinds_and_point_order(tmp_path: Path) -> None:
    declared = {
        "classes": [
            {"name": "wire", "kind": "instances"},
            {"name": "tip", "kind": "points", "point_names": ["root", "end"]},
        ],
        "frames": [{"stem": "a", "objects": [{"class": "tip", "points": {"end": [1, 1]}}]}],
    }
    learned, _ = read_classes(_dataset(tmp_path, declared), ["tip", "wire"])
    assert learned == (
        LearnedClass("tip", "points", ("root", "end")),
        LearnedClass("wire", "instances"),
    )


@pytest.mark.parametrize(
    ("spoil", "names", "message"),
    [
        (
            lambda root: None,
            ["wire", "arc"],
            "points in manifest.json); it holds spatter, tip, wire.",  # what there is
        ),
        (
            lambda root: (root / "classes/wire/c.png").write_bytes(b"\x89PNG broken"),
            ["wire"],
            "classes/wire/c.png: ",
        ),
        (
            lambda root: (root / "classes/wire/b.png").write_bytes(
                encode_mask_png(np.ones((H, W + 1), bool))
            ),
            ["wire"],
            "b.png is 49×32 but its image 48×32",
        ),
        (
            lambda root: (root / "classes/wire/zz.png").write_bytes(encode_mask_png(_box(0, 0))),
            ["wire"],
            "belongs to no image of the DATASET",
        ),
        (
            lambda root: (root / "manifest.json").write_text(
                json.dumps(
                    {
                        "frames": [
                            {"stem": "a", "objects": [{"class": "tip", "points": {"end": [1]}}]}
                        ]
                    }
                )
            ),
            ["tip"],
            "the 'tip' points of 'a' are not",
        ),
        (lambda root: (root / "manifest.json").write_text("[1, 2"), ["tip"], "is not a masks"),
        (
            lambda root: (
                (root / "classes/tip").mkdir()
                or (root / "classes/tip/a.png").write_bytes(encode_mask_png(_box(0, 0)))
            ),
            ["tip"],
            "has both masks",
        ),
    ],
)
def test_what_it_cannot_read_is_one_sentence_naming_it(
    tmp_path: Path, spoil, names: list[str], message: str
) -> None:
    root = _dataset(tmp_path)
    spoil(root)
    with pytest.raises(InvalidInputError) as caught:
        _, frames = read_classes(root, names)
        list(frames)
    assert message in caught.value.message and caught.value.message.count(". ") == 0


def test_a_resumed_run_keeps_learning_its_classes(tmp_path: Path) -> None:
    """``train_from_folder`` with ``classes`` records them; resumed without naming them, the
    run reads the same classes again, and naming others is refused."""
    data, out = _dataset(tmp_path / "data"), tmp_path / "model"
    first = train_from_folder(
        data, out, TINY_STUDENT, tiny_config(epochs=1), classes=["wire", "tip"]
    )
    assert set(first.metrics["classes"]) == {"wire", "tip"}
    assert [c.name for c in read_student_config(out).classes] == ["wire", "tip"]
    train_from_folder(data, out, None, tiny_config(epochs=2), resume=True)
    last = json.loads((out / "metrics.json").read_text())["last"]
    assert last["epoch"] == 2 and set(last["classes"]) == {"wire", "tip"}
    # each held-out frame labels one of them: measured, so read from the DATASET again
    assert sum(figures["frames"] for figures in last["classes"].values()) >= 1
    with pytest.raises(InvalidInputError, match="another student configuration"):
        train_from_folder(data, out, None, tiny_config(epochs=3), resume=True, classes=["wire"])
