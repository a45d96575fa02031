"""The review stage (`WELDPOOL_REVIEW_STAGE`): off, a saved label counts at once, as before;
on, an annotator's label awaits a reviewer, trains only once approved, and can be sent back
with a comment; the history shows who decided."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Role
from app.training.service import training_frame_ids
from tests.factories import random_images, upload_frames
from tests.helpers import auth, corrected_label


def _mask() -> np.ndarray:
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:40] = True
    return mask


def _setup(client: TestClient, make_user):  # type: ignore[no-untyped-def]
    _, reviewer = make_user("rita", Role.reviewer)
    _, annotator = make_user("anna")
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(reviewer)).json()
    frames = upload_frames(
        client, reviewer, random_images([("a.png", 1), ("b.png", 2)]), sequence_id=run["id"]
    )
    return reviewer, annotator, [f["id"] for f in frames]


def _decide(client: TestClient, token: str, frame_id: int, **body: object):  # type: ignore[no-untyped-def]
    return client.post(f"/api/v1/frames/{frame_id}/label/review", json=body, headers=auth(token))


def test_with_the_stage_off_a_saved_label_counts_at_once(
    client: TestClient, make_user, session_factory
) -> None:
    reviewer, annotator, (frame, _) = _setup(client, make_user)
    saved = client.put(
        f"/api/v1/frames/{frame}/label", json=corrected_label(_mask()), headers=auth(annotator)
    )
    assert saved.status_code == 200 and saved.json()["review"] is None
    with session_factory() as session:
        assert training_frame_ids(session) == [frame]
    refused = _decide(client, reviewer, frame, decision="approve", base_revision=1)
    assert refused.status_code == 400 and "review stage is off" in refused.json()["detail"]
    listed = client.get("/api/v1/frames", params={"review": "approved"}, headers=auth(reviewer))
    assert [f["id"] for f in listed.json()["items"]] == [frame]  # NULL counts as approved


def test_with_the_stage_on_an_annotators_label_trains_only_once_approved(
    client: TestClient, make_user, session_factory
) -> None:
    client.app.state.settings.review_stage = True  # type: ignore[attr-defined]
    reviewer, annotator, (frame, other) = _setup(client, make_user)
    saved = client.put(
        f"/api/v1/frames/{frame}/label", json=corrected_label(_mask()), headers=auth(annotator)
    )
    assert saved.json()["review"] == "awaiting"
    own = client.put(
        f"/api/v1/frames/{other}/label", json=corrected_label(_mask()), headers=auth(reviewer)
    )
    assert own.json()["review"] == "approved"  # a reviewer's own label needs no second look
    with session_factory() as session:
        assert training_frame_ids(session) == [other]

    def listed(state: str) -> list[int]:
        page = client.get("/api/v1/frames", params={"review": state}, headers=auth(reviewer))
        return [f["id"] for f in page.json()["items"]]

    assert listed("awaiting") == [frame] and listed("approved") == [other]
    detail = client.get(f"/api/v1/frames/{frame}", headers=auth(annotator)).json()
    assert detail["label"]["review"] == "awaiting"

    assert _decide(client, annotator, frame, decision="approve", base_revision=1).status_code == 403
    bare = _decide(client, reviewer, frame, decision="return", base_revision=1)
    assert bare.status_code == 400 and "needs a comment" in bare.json()["detail"]
    stale = _decide(client, reviewer, frame, decision="approve", base_revision=7)
    assert stale.status_code == 409 and stale.json()["revision"] == 1
    returned = _decide(
        client, reviewer, frame, decision="return", base_revision=1, comment="The wire tip is in."
    )
    assert returned.status_code == 200
    assert returned.json()["review"] == "returned" and returned.json()["revision"] == 2
    assert returned.json()["review_comment"] == "The wire tip is in."
    assert listed("returned") == [frame]
    with session_factory() as session:
        assert training_frame_ids(session) == [other]

    again = client.put(
        f"/api/v1/frames/{frame}/label",
        json=corrected_label(_mask(), base_revision=2),
        headers=auth(annotator),
    )
    assert again.json()["review"] == "awaiting" and again.json()["review_comment"] is None
    approved = _decide(client, reviewer, frame, decision="approve", base_revision=3)
    assert approved.status_code == 200 and approved.json()["review"] == "approved"
    assert approved.json()["updated_by"] == "rita"
    twice = _decide(client, reviewer, frame, decision="approve", base_revision=4)
    assert twice.status_code == 409 and "approved already" in twice.json()["detail"]
    with session_factory() as session:
        assert sorted(training_frame_ids(session)) == sorted([frame, other])

    history = client.get(f"/api/v1/frames/{frame}/label/history", headers=auth(annotator)).json()
    assert [(h["user"], h["review"], h["review_comment"]) for h in history] == [
        ("anna", "awaiting", None),
        ("rita", "returned", "The wire tip is in."),
        ("anna", "awaiting", None),
        ("rita", "approved", None),
    ]
