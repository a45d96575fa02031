"""What a foreign file's hand-placed pool keypoints become: validation keypoints by default
(the frame joins the validation split and does not train), or the label's own on request."""

from __future__ import annotations

import json

import pytest

from app.core.models import Role
from tests.helpers import auth, image_bytes
from tests.imports.common import H, W, start_import, stored_labels, zipped

POINTS = [[12.0, 12.0], [48.0, 38.0], [30.0, 20.0]]


def _coco() -> bytes:
    flat = [v for x, y in POINTS for v in (x, y, 2)]
    coco = {
        "images": [{"id": 1, "file_name": "k.png", "width": W, "height": H}],
        "annotations": [
            {
                "id": 1,
                "image_id": 1,
                "category_id": 1,
                "keypoints": flat,
                "segmentation": [[10, 10, 50, 10, 50, 40, 10, 40]],
            },
        ],
        "categories": [{"id": 1, "name": "weld_pool", "keypoints": ["a", "b", "c"]}],
    }
    return zipped({"a.json": json.dumps(coco).encode(), "k.png": image_bytes(W, H, seed=77)})


@pytest.mark.parametrize("role", ["validation", "label"])
def test_hand_placed_keypoints_go_where_the_import_says(client, make_user, role: str) -> None:
    _, token = make_user("placer", Role.annotator)
    result = start_import(client, token, _coco(), "coco", keypoints=role)["result"]
    assert result["labels"] == 1 and result["refused"] == []
    ((frame, label),) = list(stored_labels(client, token))
    manual = client.get(f"/api/v1/frames/{frame['id']}/validation-keypoints", headers=auth(token))
    detail = client.get(f"/api/v1/frames/{frame['id']}", headers=auth(token)).json()
    if role == "validation":
        assert result["keypoints"] == 1 and manual.json()["keypoints"] == POINTS
        assert detail["split"] == "validation"
        assert label["keypoints"] != POINTS  # Algorithm 1's on the mask
    else:
        assert result["keypoints"] == 0 and manual.status_code == 404
        assert detail["split"] == "train" and label["keypoints"] == POINTS
