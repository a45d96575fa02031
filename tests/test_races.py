"""Concurrent duplicates end in one success and 409s, never a 500 (SQLite and PostgreSQL).

Each race starts its requests at one barrier, several rounds, so that the check-then-insert
window of the service is hit for real; the unique constraints decide, and the loser is told.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Role, User
from tests.helpers import age_stored_files, auth, corrected_label, image_bytes, write_video

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


def test_one_user_name_in_several_cases_at_once(client: TestClient, admin: str) -> None:
    """'Twin0', 'tWin0', … at once: one user, the others 409 (the index on lower(username))."""
    for round_ in range(ROUNDS):
        names = [f"twin{round_}"[:i] + f"twin{round_}"[i:].upper() for i in range(RACERS)]
        statuses = at_once(
            RACERS,
            lambda i, names=names: client.post(
                "/api/v1/users",
                json={"username": names[i], "password": "long enough 1"},
                headers=auth(admin),
            ),
        )
        assert statuses == [201] + [409] * (RACERS - 1), statuses


def test_first_validation_keypoints_at_once(client: TestClient, admin: str) -> None:
    files = [("files", (f"f{i}.png", image_bytes(seed=40 + i), "image/png")) for i in range(ROUNDS)]
    stored = client.post("/api/v1/frames", files=files, headers=auth(admin)).json()["stored"]
    for frame in stored:
        url = f"/api/v1/frames/{frame['id']}/validation-keypoints"
        answers: dict[int, Any] = {}

        def place(i: int, url: str = url, answers: dict[int, Any] = answers) -> Any:
            body = {"keypoints": [[5.0 + i, 6.0]], "base_revision": 0}  # the first ones
            answers[i] = client.put(url, json=body, headers=auth(admin))
            return answers[i]

        statuses = at_once(RACERS, place)
        assert statuses == [200] + [409] * (RACERS - 1), statuses
        winner = next(i for i, a in answers.items() if a.status_code == 200)
        stored = client.get(url, headers=auth(admin)).json()
        assert stored["keypoints"] == [[5.0 + winner, 6.0]] and stored["revision"] == 1
        loser = next(a for a in answers.values() if a.status_code == 409)
        assert loser.json()["revision"] == 1 and loser.json()["updated_by"] == "boss"


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


def test_uploads_into_a_run_while_it_is_deleted_are_stored_and_counted_or_a_404(
    client: TestClient, admin: str
) -> None:
    """Uploads into a run race its deletion: an upload that loses is told the run is gone (a
    404, was a 500 on the foreign key), and the deletion counts every frame it took, those
    uploaded after it listed the run's frames included (was: only the listed ones)."""
    for round_ in range(ROUNDS):
        run = client.post(
            "/api/v1/sequences", json={"name": f"doomed {round_}"}, headers=auth(admin)
        ).json()["id"]
        first = [("files", ("0.png", image_bytes(seed=3000 + 10 * round_), "image/png"))]
        assert (
            client.post(
                "/api/v1/frames", files=first, data={"sequence_id": str(run)}, headers=auth(admin)
            ).status_code
            == 201
        )
        answers: dict[int, Any] = {}

        def racer(i: int, run: int = run, round_: int = round_, answers: dict = answers) -> Any:
            if i == 0:
                answers[i] = client.delete(
                    f"/api/v1/sequences/{run}", params={"force": "true"}, headers=auth(admin)
                )
            else:
                content = image_bytes(seed=3000 + 10 * round_ + i)
                answers[i] = client.post(
                    "/api/v1/frames",
                    files=[("files", (f"{i}.png", content, "image/png"))],
                    data={"sequence_id": str(run)},
                    headers=auth(admin),
                )
            return answers[i]

        statuses = at_once(RACERS, racer)
        assert set(statuses) <= {200, 201, 404} and 500 not in statuses, statuses
        assert answers[0].status_code == 200
        for answer in (answers[i] for i in range(1, RACERS)):
            if answer.status_code == 404:
                assert answer.json()["detail"] == f"There is no sequence {run}."
        stored = [a.json()["stored"][0]["id"] for a in answers.values() if a.status_code == 201]
        alive = [
            i
            for i in stored
            if client.get(f"/api/v1/frames/{i}", headers=auth(admin)).status_code == 200
        ]
        # Every frame stored into the run before the deletion's commit went with it, counted.
        assert answers[0].json()["deleted_frames"] == 1 + len(stored) - len(alive)
        assert alive == []  # none is stored into a run after it is gone


def test_one_frame_deleted_by_several_at_once_is_one_200_and_404s(
    client: TestClient, admin: str
) -> None:
    files = [("files", (f"d{i}.png", image_bytes(seed=70 + i), "image/png")) for i in range(ROUNDS)]
    stored = client.post("/api/v1/frames", files=files, headers=auth(admin)).json()["stored"]
    for frame in stored:
        url = f"/api/v1/frames/{frame['id']}"
        statuses = at_once(RACERS, lambda i, url=url: client.delete(url, headers=auth(admin)))
        assert statuses == [200] + [404] * (RACERS - 1), statuses


def test_one_run_deleted_by_several_at_once_is_one_200_and_404s(
    client: TestClient, admin: str
) -> None:
    """The losers waited on the run's row lock and then answered 200 with nothing deleted
    (PostgreSQL), or a 404 naming a frame (SQLite)."""
    for round_ in range(ROUNDS):
        run = client.post(
            "/api/v1/sequences", json={"name": f"twice {round_}"}, headers=auth(admin)
        ).json()["id"]
        files = [
            ("files", (f"{i}.png", image_bytes(seed=4000 + 10 * round_ + i), "image/png"))
            for i in range(3)
        ]
        client.post(
            "/api/v1/frames", files=files, data={"sequence_id": str(run)}, headers=auth(admin)
        )
        answers: dict[int, Any] = {}

        def delete(i: int, run: int = run, answers: dict = answers) -> Any:
            answers[i] = client.delete(f"/api/v1/sequences/{run}", headers=auth(admin))
            return answers[i]

        assert at_once(RACERS, delete) == [200] + [404] * (RACERS - 1)
        for answer in answers.values():
            if answer.status_code == 200:
                assert answer.json()["deleted_frames"] == 3
            else:
                assert answer.json()["detail"] == f"There is no sequence {run}."


def test_a_video_uploaded_into_a_run_while_it_is_deleted_is_stored_or_a_404(
    client: TestClient, admin: str, tmp_path: Path
) -> None:
    """The video's row met the foreign key of a run deleted while the upload was probed (a 500):
    now the run's 404, or a 409 when the run went after the video's row was written."""
    video = write_video(tmp_path / "run.avi", 12).read_bytes()
    for round_ in range(ROUNDS):
        run = client.post(
            "/api/v1/sequences", json={"name": f"film {round_}"}, headers=auth(admin)
        ).json()["id"]
        answers: dict[int, Any] = {}

        def racer(i: int, run: int = run, answers: dict = answers) -> Any:
            if i == 0:
                answers[i] = client.delete(f"/api/v1/sequences/{run}", headers=auth(admin))
            else:
                answers[i] = client.post(
                    "/api/v1/videos",
                    files=[("file", (f"v{i}.avi", video, "video/avi"))],
                    data={"sequence_id": str(run)},
                    headers=auth(admin),
                )
            return answers[i]

        statuses = at_once(3, racer)
        assert answers[0].status_code == 200 and set(statuses) <= {200, 202, 404, 409}, statuses
        for answer in (answers[1], answers[2]):
            if answer.status_code == 404:  # the run was gone when the video's row was written
                assert answer.json()["detail"] == f"There is no sequence {run}."
            if answer.status_code == 409:  # gone before the row took its extraction job
                assert "changed or deleted by someone else meanwhile" in answer.json()["detail"]


def _delete_or_label(
    client: TestClient, admin: str, frame_id: int, mask: np.ndarray, i: int
) -> Any:
    """Racer 0 deletes the frame, 1 saves its label, 2 its validation keypoints."""
    if i == 0:
        return client.post(
            "/api/v1/frames/delete",
            json={"frame_ids": [frame_id], "force": True},
            headers=auth(admin),
        )
    if i == 1:
        return client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(admin)
        )
    return client.put(
        f"/api/v1/frames/{frame_id}/validation-keypoints",
        json={"keypoints": [[5, 5], [20, 20], [30, 10], [40, 30]]},
        headers=auth(admin),
    )


def test_saving_labels_while_their_frames_are_deleted_never_answers_500(
    client: TestClient, admin: str
) -> None:
    """A label saved (or validation keypoints set) while its frame is deleted: 200 or 404,
    never a 500."""
    run = client.post("/api/v1/sequences", json={"name": "labels"}, headers=auth(admin)).json()
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:40] = True
    statuses: list[int] = []
    for round_ in range(12):
        files = [("files", (f"{round_}.png", image_bytes(seed=3000 + round_), "image/png"))]
        frame = client.post(
            "/api/v1/frames", files=files, data={"sequence_id": str(run["id"])}, headers=auth(admin)
        ).json()["stored"][0]
        race = functools.partial(_delete_or_label, client, admin, frame["id"], mask)
        statuses += at_once(3, race)
    assert set(statuses) <= {200, 404, 409} and 200 in statuses, statuses


def test_two_admins_demoting_each_other_at_once_leave_one_admin(
    client: TestClient, make_user, session_factory
) -> None:
    """Each demotion counted the admins before the other's commit and both passed (PostgreSQL:
    no admin left, 2 rounds of 5): the admins' rows are locked before the count."""
    survivor = make_user("first", Role.admin)
    for round_ in range(4 * ROUNDS):
        rival = make_user(f"rival{round_}", Role.admin)
        pair = [survivor, rival]

        def demote(i: int, pair: list = pair) -> Any:
            other = pair[1 - i][0].id
            return client.patch(
                f"/api/v1/users/{other}", json={"role": "reviewer"}, headers=auth(pair[i][1])
            )

        statuses = at_once(2, demote)
        assert statuses in ([200, 403], [200, 409]), statuses  # 403: demoted before it asked
        with session_factory() as session:
            admins = session.scalars(
                sa.select(User).where(User.role == Role.admin, User.is_active.is_(True))
            ).all()
        assert len(admins) == 1, [a.username for a in admins]
        survivor = next(p for p in pair if p[0].id == admins[0].id)


def test_reviewers_taking_the_next_frames_at_once_never_share_one(
    client: TestClient, make_user
) -> None:
    """Each read the same head of the queue and handed it out (both backends): now a frame
    goes to whoever's conditional update takes it first, and the others take the next ones."""
    reviewers = [make_user(f"rev{i}", Role.reviewer) for i in range(RACERS)]
    each = 3
    for round_ in range(ROUNDS):
        run = client.post(
            "/api/v1/sequences", json={"name": f"queue {round_}"}, headers=auth(reviewers[0][1])
        ).json()["id"]
        files = [
            ("files", (f"{i}.png", image_bytes(seed=5000 + 100 * round_ + i), "image/png"))
            for i in range(RACERS * each)
        ]
        client.post(
            "/api/v1/frames",
            files=files,
            data={"sequence_id": str(run)},
            headers=auth(reviewers[0][1]),
        )
        answers: dict[int, Any] = {}

        def take(i: int, run: int = run, answers: dict = answers) -> Any:
            body = {"next": each, "sequence_id": run, "assignee_id": reviewers[i][0].id}
            answers[i] = client.post(
                "/api/v1/frames/assign", json=body, headers=auth(reviewers[i][1])
            )
            return answers[i]

        assert at_once(RACERS, take) == [200] * RACERS
        handed = [answers[i].json()["frame_ids"] for i in range(RACERS)]
        assert all(len(ids) == each for ids in handed), handed
        flat = [frame for ids in handed for frame in ids]
        assert len(set(flat)) == len(flat) == RACERS * each, handed
