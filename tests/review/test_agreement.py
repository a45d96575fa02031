"""Agreement: a frame given to three annotators keeps their labels apart (they do not train,
and an annotator sees only her own) until a reviewer merges them or approves one; its agreement
and the run's are checked against values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from app.training.service import training_frame_ids
from tests.factories import frame_ids, random_images
from tests.helpers import auth, mask_b64


def _mask(right: int) -> np.ndarray:
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:right] = True
    return mask


# anna 600 px, tina 400 px inside it, otto 300 px inside both: IoUs 0.5, 2/3, 0.75.
OWN = {"anna": (40, [[10.0, 10.0], [39.0, 29.0]]), "otto": (25, [[10.0, 10.0], [24.0, 29.0]])}
OWN["tina"] = (30, [[10.0, 10.0], [29.0, 29.0]])


def _own(client: TestClient, token: str, frame: int, name: str):  # type: ignore[no-untyped-def]
    right, points = OWN[name]
    body = {"mask_png": mask_b64(_mask(right)), "keypoints": points}
    return client.put(f"/api/v1/frames/{frame}/overlap/mine", json=body, headers=auth(token))


def test_labels_kept_apart_measured_and_merged(
    client: TestClient, make_user, session_factory
) -> None:
    _, rita = make_user("rita", Role.reviewer)
    people = {name: make_user(name) for name in ("anna", "otto", "tina")}
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(rita)).json()
    f1, f2 = frame_ids(client, rita, random_images([("1", 1), ("2", 2)]), sequence_id=run["id"])
    ids = [user.id for user, _ in people.values()]
    one = client.post(
        "/api/v1/frames/overlap", json={"frame_ids": [f1], "user_ids": ids[:1]}, headers=auth(rita)
    )
    assert one.status_code == 422  # agreement needs two people or more
    given = client.post(
        "/api/v1/frames/overlap", json={"frame_ids": [f1, f2], "user_ids": ids}, headers=auth(rita)
    )
    assert given.status_code == 200 and given.json()["given"] == 6
    by_annotator = client.post(
        "/api/v1/frames/overlap",
        json={"frame_ids": [f1], "user_ids": ids},
        headers=auth(people["anna"][1]),
    )
    assert by_annotator.status_code == 403

    def due(token: str) -> tuple[int, list[int]]:
        work = client.get("/api/v1/users/me/work", headers=auth(token)).json()
        page = client.get("/api/v1/frames", params={"assignee": "me"}, headers=auth(token))
        return work["assigned"], [f["id"] for f in page.json()["items"]]

    assert due(people["otto"][1]) == (2, [f1, f2])  # each one's own label is her work
    for name, (_, token) in people.items():
        assert _own(client, token, f1, name).status_code == 200
    assert due(people["otto"][1]) == (1, [f2])
    assert _own(client, people["anna"][1], f2, "anna").status_code == 200
    _, stranger = make_user("sam")
    refused = _own(client, stranger, f1, "anna")
    assert refused.status_code == 403 and "not given to you" in refused.json()["detail"]
    with session_factory() as session:
        assert training_frame_ids(session) == []  # their own labels never train

    mine = client.get(f"/api/v1/frames/{f1}/overlap", headers=auth(people["otto"][1])).json()
    assert [label["username"] for label in mine["labels"]] == ["otto"]  # kept apart
    assert mine["mask_iou"] is None and mine["labelled"] == 3
    seen = client.get(f"/api/v1/frames/{f1}/overlap", headers=auth(rita)).json()
    assert [label["username"] for label in seen["labels"]] == ["anna", "otto", "tina"]
    assert seen["mask_iou"] == pytest.approx((0.5 + 2 / 3 + 0.75) / 3)
    # keypoints: one of two points off, both ways, by 15 px anna–otto (7.5), 10 px anna–tina
    # (5) and 5 px otto–tina (2.5).
    assert seen["keypoint_px"] == pytest.approx((7.5 + 5 + 2.5) / 3)
    figures = client.get("/api/v1/metrics", headers=auth(rita)).json()["agreement"]
    assert figures == [  # f2 has one label: no agreement to measure there
        {
            "sequence_id": run["id"],
            "sequence": "run",
            "frames": 1,
            "mask_iou": pytest.approx(seen["mask_iou"]),
            "keypoint_px": pytest.approx(seen["keypoint_px"]),
            "classes": [],  # the pool alone is configured
            "tags_differ": 0,
        }
    ]

    both = {"choose": ids[0], "merge": True}
    assert (
        client.post(
            f"/api/v1/frames/{f1}/overlap/settle", json=both, headers=auth(rita)
        ).status_code
        == 400
    )
    merged = client.post(
        f"/api/v1/frames/{f1}/overlap/settle", json={"merge": True}, headers=auth(rita)
    )
    assert merged.status_code == 200 and merged.json()["updated_by"] == "rita"
    import base64

    from weldpool_core.io import decode_mask_png

    mask = decode_mask_png(base64.b64decode(merged.json()["mask_png"]))
    assert mask.sum() == 400 and np.array_equal(mask, _mask(30))  # two of three say pool
    absent = client.post(
        f"/api/v1/frames/{f2}/overlap/settle", json={"choose": ids[1]}, headers=auth(rita)
    )
    assert absent.status_code == 400 and "no label" in absent.json()["detail"]
    chosen = client.post(
        f"/api/v1/frames/{f2}/overlap/settle", json={"choose": ids[0]}, headers=auth(rita)
    )
    assert chosen.status_code == 200 and chosen.json()["keypoints"] == OWN["anna"][1]
    with session_factory() as session:
        assert sorted(training_frame_ids(session)) == [f1, f2]  # the settled labels only
