"""Concurrent duplicates end in one success and 409s, never a 500 (SQLite and PostgreSQL).

Each race starts its requests at one barrier, several rounds, so that the check-then-insert
window of the service is hit for real; the unique constraints decide, and the loser is told.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.models import Role
from tests.helpers import age_stored_files, auth, image_bytes

ROUNDS, RACERS = 5, 6


def at_once(count: int, call: Callable[[int], Any]) -> list[int]:
    """Run ``call(i)`` in ``count`` threads released together; their HTTP statuses."""
    barrier = threading.Barrier(count)
    statuses: list[int] = [0] * count

    def run(i: int) -> None:
        barrier.wait()
        statuses[i] = call(i).status_code

    threads = [threading.Thread(target=run, args=(i,)) for i in range(count)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    return sorted(statuses)


@pytest.fixture
def admin(make_user) -> str:
    return str(make_user("boss", Role.admin)[1])


def test_same_sequence_name_at_once(client: TestClient, admin: str) -> None:
    for round_ in range(ROUNDS):
        body = {"name": f"run {round_}"}
        statuses = at_once(
            RACERS,
            lambda _, body=body: client.post("/api/v1/sequences", json=body, headers=auth(admin)),
        )
        assert statuses == [201] + [409] * (RACERS - 1), statuses


def test_same_rename_at_once(client: TestClient, admin: str) -> None:
    ids = [
        client.post("/api/v1/sequences", json={"name": f"s{i}"}, headers=auth(admin)).json()["id"]
        for i in range(RACERS * ROUNDS)
    ]
    for round_ in range(ROUNDS):
        mine = ids[round_ * RACERS : (round_ + 1) * RACERS]
        statuses = at_once(
            RACERS,
            lambda i, mine=mine, round_=round_: client.patch(
                f"/api/v1/sequences/{mine[i]}",
                json={"name": f"taken {round_}"},
                headers=auth(admin),
            ),
        )
        assert statuses == [200] + [409] * (RACERS - 1), statuses


def test_same_user_name_at_once(client: TestClient, admin: str) -> None:
    for round_ in range(ROUNDS):
        body = {"username": f"twin{round_}", "password": "long enough 1"}
        statuses = at_once(
            RACERS,
            lambda _, body=body: client.post("/api/v1/users", json=body, headers=auth(admin)),
        )
        assert statuses == [201] + [409] * (RACERS - 1), statuses


def test_first_validation_keypoints_at_once(client: TestClient, admin: str) -> None:
    files = [("files", (f"f{i}.png", image_bytes(seed=40 + i), "image/png")) for i in range(ROUNDS)]
    stored = client.post("/api/v1/frames", files=files, headers=auth(admin)).json()["stored"]
    for frame in stored:
        url = f"/api/v1/frames/{frame['id']}/validation-keypoints"
        statuses = at_once(
            RACERS,
            lambda i, url=url: client.put(
                url, json={"keypoints": [[5.0 + i, 6.0]]}, headers=auth(admin)
            ),
        )
        assert set(statuses) <= {200, 409} and 200 in statuses, statuses


def _delete_or_upload(
    client: TestClient, admin: str, answers: dict, old: int, new: int, files: list, i: int
) -> Any:
    """Racer 0 deletes run ``old``; racer 1 uploads ``files`` to run ``new``."""
    if i == 0:
        answers["delete"] = client.delete(
            f"/api/v1/sequences/{old}", params={"force": "true"}, headers=auth(admin)
        )
        return answers["delete"]
    answers["upload"] = client.post(
        "/api/v1/frames", files=files, data={"sequence_id": str(new)}, headers=auth(admin)
    )
    return answers["upload"]


def test_deleting_a_run_while_its_content_is_uploaded_to_another_loses_nothing(
    client: TestClient, admin: str, settings
) -> None:
    """A run is deleted while the same files are uploaded to another run: every frame the
    upload acknowledged keeps its image (content is shared by hash, so the deletion's files
    are the upload's too). The files are old, so a collector that ignored the upload's claim
    would remove them."""
    rounds, count = 8, 12
    lost = acknowledged = 0
    for round_ in range(rounds):
        contents = [image_bytes(seed=1000 + 50 * round_ + i) for i in range(count)]
        files = [("files", (f"{i}.png", c, "image/png")) for i, c in enumerate(contents)]
        old, new = (
            client.post(
                "/api/v1/sequences", json={"name": f"{name} {round_}"}, headers=auth(admin)
            ).json()["id"]
            for name in ("old", "new")
        )
        stored = client.post(
            "/api/v1/frames", files=files, data={"sequence_id": str(old)}, headers=auth(admin)
        )
        assert stored.status_code == 201
        age_stored_files(settings.home, settings.file_grace_s + 60)
        answers: dict[str, Any] = {}
        race = functools.partial(_delete_or_upload, client, admin, answers, old, new, files)
        assert at_once(2, race) == [200, 201]
        for frame in answers["upload"].json()["stored"]:
            acknowledged += 1
            image = client.get(f"/api/v1/frames/{frame['id']}/image", headers=auth(admin))
            lost += (
                image.status_code != 200
                or image.content != contents[int(frame["original_name"].removesuffix(".png"))]
            )
    assert acknowledged == rounds * count and lost == 0
