"""Work that finds its person (`GET /users/me/work`, `GET /frames?assignee=me`): a label sent
back is handed to its annotator and leads her list with the comment; a reviewer counts what
awaits approval; each count is the length of the list it opens."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import frame_ids, random_images
from tests.helpers import auth, corrected_label


def _mask() -> np.ndarray:
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:40] = True
    return mask


def _work(client: TestClient, token: str) -> dict[str, int]:
    answer = client.get("/api/v1/users/me/work", headers=auth(token))
    assert answer.status_code == 200
    return answer.json()


def _ids(client: TestClient, token: str, **params: object) -> list[int]:
    page = client.get("/api/v1/frames", params=params, headers=auth(token))
    assert page.status_code == 200, page.text
    return [f["id"] for f in page.json()["items"]]


def test_the_work_of_an_annotator_and_a_reviewer(client: TestClient, make_user) -> None:
    client.app.state.settings.review_stage = True  # type: ignore[attr-defined]
    _, rita = make_user("rita", Role.reviewer)
    anna_user, anna = make_user("anna")
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(rita)).json()
    names = [(f"{i}.png", i + 1) for i in range(4)]
    a, b, c, d = frame_ids(client, rita, random_images(names), sequence_id=run["id"])
    assert _work(client, anna) == {"sent_back": 0, "assigned": 0, "awaiting_review": 0}

    handed = {"frame_ids": [b, c, d], "assignee_id": anna_user.id}
    assert client.post("/api/v1/frames/assign", json=handed, headers=auth(rita)).status_code == 200
    assert _work(client, anna) == {"sent_back": 0, "assigned": 3, "awaiting_review": 0}
    # Frame a is nobody's; anna labels it anyway, and c, which is hers.
    for frame in (a, c):
        saved = client.put(
            f"/api/v1/frames/{frame}/label", json=corrected_label(_mask()), headers=auth(anna)
        )
        assert saved.json()["review"] == "awaiting"
    assert _work(client, anna) == {"sent_back": 0, "assigned": 2, "awaiting_review": 0}
    assert _work(client, rita) == {"sent_back": 0, "assigned": 0, "awaiting_review": 2}
    assert _ids(client, rita, review="awaiting") == [a, c]

    returned = client.post(
        f"/api/v1/frames/{a}/label/review",
        json={"decision": "return", "base_revision": 1, "comment": "The wire tip is in."},
        headers=auth(rita),
    )
    assert returned.status_code == 200
    assert _work(client, anna) == {"sent_back": 1, "assigned": 2, "awaiting_review": 0}
    assert _work(client, rita)["awaiting_review"] == 1

    # Her list with no other filter: what was sent back first (with the comment), then the
    # frames handed to her that nobody has labelled; c, awaiting approval, is not hers to do.
    page = client.get("/api/v1/frames", params={"assignee": "me"}, headers=auth(anna)).json()
    assert [f["id"] for f in page["items"]] == [a, b, d] and page["total"] == 3
    assert page["items"][0]["review"] == "returned"
    assert page["items"][0]["review_comment"] == "The wire tip is in."
    assert page["items"][0]["assignee"] == "anna"  # sent back: handed to the one who saved it
    assert _ids(client, anna, assignee="me", order="-id") == [a, d, b]  # sent back leads
    # Each count opens its own list.
    assert _ids(client, anna, assignee="me", review="returned") == [a]
    assert _ids(client, anna, assignee="me", status="unreviewed") == [b, d]
    assert _ids(client, anna, assignee="me", status="all") == [a, b, c, d]
    assert _ids(client, anna, assignee="me", offset=2, limit=2) == [d]
    cursor = client.get(
        "/api/v1/frames", params={"assignee": "me", "after": "id~1"}, headers=auth(anna)
    )
    assert cursor.status_code == 400 and "offset" in cursor.json()["detail"]

    again = client.put(
        f"/api/v1/frames/{a}/label",
        json=corrected_label(_mask(), base_revision=2),
        headers=auth(anna),
    )
    assert again.json()["review"] == "awaiting"
    assert _work(client, anna) == {"sent_back": 0, "assigned": 2, "awaiting_review": 0}
    assert _work(client, rita)["awaiting_review"] == 2


def test_with_the_stage_off_nothing_awaits_or_is_sent_back(client: TestClient, make_user) -> None:
    _, rita = make_user("rita", Role.reviewer)
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(rita)).json()
    (frame,) = frame_ids(client, rita, random_images([("a.png", 1)]), sequence_id=run["id"])
    _, anna = make_user("anna")
    client.put(f"/api/v1/frames/{frame}/label", json=corrected_label(_mask()), headers=auth(anna))
    assert _work(client, rita) == {"sent_back": 0, "assigned": 0, "awaiting_review": 0}
    assert client.get("/api/v1/users/me/work").status_code == 401
