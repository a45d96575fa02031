"""Before a training starts, and in the answer that starts it: how many labels it would learn
from and be measured on, and a warning when the promotion gate could not measure the version."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.helpers import auth, corrected_label, image_bytes, wait_for_job


def _labelled(client: TestClient, token: str, seeds: range) -> list[int]:
    files = [("files", (f"p{s}.png", image_bytes(160, 100, seed=s), "image/png")) for s in seeds]
    stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    ids = [f["id"] for f in stored]
    for frame_id in ids:
        mask = np.zeros((100, 160), bool)
        mask[30:70, 20:120] = True
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200, saved.text
    return ids


def test_the_plan_warns_when_the_gate_could_not_measure_the_version(
    client: TestClient, make_user
) -> None:
    _, token = make_user("trainer", Role.reviewer)
    _, annotator = make_user("anna")
    plan = client.get("/api/v1/student/training-plan", headers=auth(annotator)).json()
    nothing = "There are no accepted or corrected labels outside the validation split to train on."
    assert plan == {
        "labels": 0,
        "validation_frames": 0,
        "held_out": 0,
        "needed": 3,
        "warning": nothing,
    }
    refused = client.post("/api/v1/student/train", json={"epochs": 1}, headers=auth(token))
    assert refused.status_code == 400 and refused.json()["detail"] == nothing

    _labelled(client, token, range(60, 61))
    one = client.get("/api/v1/student/training-plan", headers=auth(token)).json()
    assert (one["labels"], one["held_out"], one["needed"]) == (1, 0, 3)
    assert one["warning"].startswith(
        "Only 1 label to train on and no frame in the validation split: the promotion gate "
        "measures a version on labels held out from its training, which takes at least 3 labels"
    )
    started = client.post("/api/v1/student/train", json={"epochs": 1}, headers=auth(token))
    assert started.status_code == 202
    assert started.json() == one | {"job_id": started.json()["job_id"]}  # says it again
    again = client.post("/api/v1/student/train", json={"epochs": 1}, headers=auth(token))
    assert again.status_code in (202, 409)  # one training at a time (202: the first finished)
    wait_for_job(client, started.json()["job_id"], token)
    if again.status_code == 202:
        wait_for_job(client, again.json()["job_id"], token)

    _labelled(client, token, range(61, 63))  # 3 labels: one is held out to measure on
    three = client.get("/api/v1/student/training-plan", headers=auth(token)).json()
    assert (three["labels"], three["held_out"], three["warning"]) == (2, 1, None)


def test_a_validation_frame_is_enough_to_measure_one_label(client: TestClient, make_user) -> None:
    _, token = make_user("trainer", Role.reviewer)
    _, second = _labelled(client, token, range(70, 72))
    manual = client.put(
        f"/api/v1/frames/{second}/validation-keypoints",
        json={"keypoints": [[20.0, 50.0], [119.0, 50.0]]},
        headers=auth(token),
    )
    assert manual.status_code == 200, manual.text
    plan = client.get("/api/v1/student/training-plan", headers=auth(token)).json()
    assert plan == {
        "labels": 1,
        "validation_frames": 1,
        "held_out": 0,
        "needed": 1,
        "warning": None,
    }
