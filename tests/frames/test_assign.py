"""Frames handed to a person: a selection or the next of the queue, the `assignee` filter,
who may hand out, and refusals that change nothing."""

from __future__ import annotations

import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Frame, Role
from tests.factories import random_images, upload_frames
from tests.helpers import auth, image_bytes


def _ids(client: TestClient, token: str, **params: str) -> list[int]:
    page = client.get("/api/v1/frames", params={"limit": "100", **params}, headers=auth(token))
    assert page.status_code == 200, page.text
    return [f["id"] for f in page.json()["items"]]


def test_assigning_a_selection_and_the_next_of_the_queue(
    client: TestClient, make_user, session_factory
) -> None:
    _, reviewer = make_user("rev", Role.reviewer)
    ann, annotator = make_user("ann")
    bob, bob_token = make_user("bob")
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(reviewer)).json()
    frames = upload_frames(
        client,
        reviewer,
        random_images([(f"f{i}.png", i + 1) for i in range(6)]),
        sequence_id=run["id"],
    )
    ids = [f["id"] for f in frames]
    scores = {ids[0]: 0.1, ids[1]: 0.9, ids[2]: 0.5, ids[3]: 0.7, ids[4]: 0.3, ids[5]: 0.8}
    with session_factory() as session:
        for frame_id, score in scores.items():
            session.execute(sa.update(Frame).where(Frame.id == frame_id).values(uncertainty=score))
        session.commit()

    chosen = client.post(
        "/api/v1/frames/assign",
        json={"frame_ids": [ids[0], ids[4]], "assignee_id": ann.id},
        headers=auth(reviewer),
    )
    assert chosen.status_code == 200
    assert chosen.json() == {"assigned": 2, "frame_ids": [ids[0], ids[4]], "assignee": "ann"}
    assert _ids(client, annotator, assignee="me") == [ids[0], ids[4]]
    assert _ids(client, annotator, assignee=str(ann.id), order="uncertainty") == [ids[4], ids[0]]
    assert _ids(client, bob_token, assignee="me") == []
    detail = client.get(f"/api/v1/frames/{ids[0]}", headers=auth(bob_token)).json()
    assert detail["assignee"] == "ann" and detail["assignee_id"] == ann.id

    # the next two of the queue that nobody has: most uncertain first, ann's frames skipped
    handed = client.post(
        "/api/v1/frames/assign",
        json={"next": 2, "sequence_id": run["id"], "assignee_id": bob.id},
        headers=auth(reviewer),
    )
    assert handed.json()["frame_ids"] == [ids[1], ids[5]]
    again = client.post(
        "/api/v1/frames/assign", json={"next": 3, "assignee_id": bob.id}, headers=auth(reviewer)
    )
    assert again.json()["frame_ids"] == [ids[3], ids[2]]  # only these two were left
    assert _ids(client, bob_token, assignee="me", order="uncertainty") == [
        ids[1],
        ids[5],
        ids[3],
        ids[2],
    ]
    assert _ids(client, reviewer, assignee="none") == []

    back = client.post(
        "/api/v1/frames/assign",
        json={"frame_ids": [ids[1]], "assignee_id": None},
        headers=auth(reviewer),
    )
    assert back.json()["assignee"] is None
    assert _ids(client, reviewer, assignee="none") == [ids[1]]
    listed = client.get("/api/v1/frames", params={"assignee": "none"}, headers=auth(reviewer))
    assert listed.json()["items"][0]["assignee"] is None


def test_only_reviewers_hand_out_and_refusals_change_nothing(
    client: TestClient, make_user, session_factory
) -> None:
    _, reviewer = make_user("rev", Role.reviewer)
    ann, annotator = make_user("ann")
    gone, _ = make_user("gone")
    _, admin = make_user("boss", Role.admin)
    client.patch(f"/api/v1/users/{gone.id}", json={"is_active": False}, headers=auth(admin))
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(reviewer)).json()
    (frame,) = upload_frames(client, reviewer, random_images([("a.png", 1)]), sequence_id=run["id"])
    body = {"frame_ids": [frame["id"]], "assignee_id": ann.id}

    assert (
        client.post("/api/v1/frames/assign", json=body, headers=auth(annotator)).status_code == 403
    )
    cases = [
        ({"frame_ids": [frame["id"], 999999], "assignee_id": ann.id}, 404, "no frame 999999"),
        ({"frame_ids": [frame["id"]], "assignee_id": 999999}, 404, "no user 999999"),
        ({"frame_ids": [frame["id"]], "assignee_id": gone.id}, 400, "gone is deactivated"),
        ({"frame_ids": [frame["id"]], "next": 2, "assignee_id": ann.id}, 400, "not both"),
        ({"assignee_id": ann.id}, 400, "Give frame_ids or next: which frames to hand."),
        ({"next": 2, "sequence_id": 999999, "assignee_id": ann.id}, 404, "no sequence 999999"),
    ]
    for payload, code, words in cases:
        refused = client.post("/api/v1/frames/assign", json=payload, headers=auth(reviewer))
        assert refused.status_code == code, (payload, refused.text)
        assert words in refused.json()["detail"]
    with session_factory() as session:
        assert session.get(Frame, frame["id"]).assignee_id is None
    bad = client.get("/api/v1/frames", params={"assignee": "someone"}, headers=auth(reviewer))
    assert bad.status_code == 422
    names = client.get("/api/v1/users/assignable", headers=auth(reviewer)).json()
    assert [u["username"] for u in names] == ["ann", "boss", "rev"]  # not the deactivated
    assert client.get("/api/v1/users/assignable", headers=auth(annotator)).status_code == 403


def test_an_upload_names_the_other_runs_that_hold_its_content(
    client: TestClient, make_user
) -> None:
    _, token = make_user("rev", Role.reviewer)
    one = client.post("/api/v1/sequences", json={"name": "one"}, headers=auth(token)).json()
    two = client.post("/api/v1/sequences", json={"name": "two"}, headers=auth(token)).json()
    (first,) = upload_frames(client, token, random_images([("a.png", 1)]), sequence_id=one["id"])
    fresh = client.post(
        "/api/v1/frames",
        files=[
            (
                "files",
                (
                    "a-again.png",
                    image_bytes(seed=1),
                    "image/png",
                ),
            ),
            (
                "files",
                ("new.png", image_bytes(seed=9), "image/png"),
            ),
        ],
        data={"sequence_id": str(two["id"])},
        headers=auth(token),
    ).json()
    copy = next(f for f in fresh["stored"] if f["original_name"] == "a-again.png")
    assert fresh["also_in"] == [
        {
            "frame_id": copy["id"],
            "other_frame_id": first["id"],
            "sequence_id": one["id"],
            "sequence_name": "one",
        }
    ]  # the new image is in no other run: not listed
