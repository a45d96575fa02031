"""The display policy (``app.proposals.policy``): a student's proposal is shown in place of
the teacher's only when it agrees better with the reviewed labels on enough frames; a label
records the proposal it came from."""

from __future__ import annotations

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Frame, ModelVersion, Proposal, Role
from app.storage import LocalStorage
from tests.factories import frame_ids, numbered, random_images, run_teacher, upload_synthetic
from tests.helpers import auth, corrected_label
from tests.proposals.common import H, W, box, propose


def _teacher_and_student(
    client: TestClient, token: str, settings, session_factory, seed: int, count: int
) -> list[int]:
    """``count`` frames, each with a teacher proposal (IoU 0.6 against ``box(20, 60)``) and a
    proposal of student-v1 (IoU 38/42 against it)."""
    storage = LocalStorage(settings.home)
    ids = frame_ids(
        client, token, random_images(numbered(count, first_seed=seed), width=W, height=H)
    )
    with session_factory() as session:
        session.add(ModelVersion(name="student-v1", checkpoint_path=None, train_frame_ids=[]))
        session.commit()
    for frame_id in ids:
        propose(session_factory, storage, frame_id, "teacher", "t", box(30, 70))
        propose(session_factory, storage, frame_id, "student", "student-v1", box(22, 62))
    return ids


def test_the_policy_shows_a_student_only_when_it_agrees_better_on_enough_frames(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("policy", Role.reviewer)
    ids = _teacher_and_student(client, token, settings, session_factory, 400, 5)
    truth = box(20, 60)

    def shown(frame_id: int) -> str:
        body = client.get(f"/api/v1/frames/{frame_id}/proposal", headers=auth(token)).json()
        return body["source_key"]

    assert shown(ids[4]) == "teacher"  # nothing measured yet: the teacher
    for count, frame_id in enumerate(ids[:3], start=1):
        response = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(truth), headers=auth(token)
        )
        assert response.status_code == 200, response.text
        assert response.json()["mask_changed"] is True
        expected = "student:student-v1" if count >= 3 else "teacher"
        assert shown(ids[4]) == expected, count  # two frames are not enough evidence

    listing = client.get(f"/api/v1/frames/{ids[4]}/proposals", headers=auth(token)).json()
    assert [p["source"] for p in listing["items"]] == ["student", "teacher"]
    assert [p["chosen"] for p in listing["items"]] == [True, False]
    scores = {s["key"]: s for s in listing["policy"]["sources"]}
    assert scores["teacher"]["mIoU"] == pytest.approx(0.6)
    assert scores["student:student-v1"]["mIoU_common"] == pytest.approx(38 / 42)
    assert listing["policy"]["chosen"] == "student:student-v1"
    other = client.get(
        f"/api/v1/frames/{ids[4]}/proposal", params={"source": "teacher"}, headers=auth(token)
    ).json()
    assert other["source"] == "teacher" and not other["chosen"]

    # Deleting an older reviewed frame leaves two frames of evidence: the teacher again (the
    # policy is measured anew, not served from a cache keyed by the newest label only).
    deleted = client.delete(
        f"/api/v1/frames/{ids[0]}", params={"force": "true"}, headers=auth(token)
    )
    assert deleted.status_code == 200 and deleted.json()["deleted_reviewed"] == 1
    assert shown(ids[4]) == "teacher"
    assert (
        client.get(
            f"/api/v1/frames/{ids[4]}/proposal",
            params={"source": "student:nope"},
            headers=auth(token),
        ).status_code
        == 400
    )

    # a gate that found the version worse than the teacher keeps it out of the review
    with session_factory() as session:
        version = session.query(ModelVersion).filter_by(name="student-v1").one()
        version.gate = {"usable": False}
        version.promoted_at = None
        session.commit()
    # a new label revision changes the policy's fingerprint
    client.put(f"/api/v1/frames/{ids[3]}/label", json=corrected_label(truth), headers=auth(token))
    assert shown(ids[4]) == "teacher"
    with session_factory() as session:
        version = session.query(ModelVersion).filter_by(name="student-v1").one()
        version.gate = None
        version.train_frame_ids = ids[:3]  # frames it trained on do not count
        session.commit()
    label = client.get(f"/api/v1/frames/{ids[3]}/label", headers=auth(token)).json()
    client.put(
        f"/api/v1/frames/{ids[3]}/label",
        json=corrected_label(truth, base_revision=label["revision"]),
        headers=auth(token),
    )
    assert shown(ids[4]) == "teacher"


def test_a_label_records_its_proposal_and_acceptance_is_counted_per_source(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("provenance", Role.reviewer)
    storage = LocalStorage(settings.home)
    ids = frame_ids(client, token, random_images(numbered(2, first_seed=500), width=W, height=H))
    teacher = propose(session_factory, storage, ids[0], "teacher", "t", box(30, 70))
    student = propose(session_factory, storage, ids[0], "student", "student-v9", box(22, 62))
    second = propose(session_factory, storage, ids[1], "teacher", "t", box(30, 70))
    accepted = client.put(
        f"/api/v1/frames/{ids[0]}/label",
        json={"status": "accepted", "base_revision": 0, "proposal_id": student},
        headers=auth(token),
    ).json()
    assert accepted["proposal_id"] == student and accepted["mask_changed"] is False
    same = client.put(  # the teacher's mask, sent back as it was: unchanged
        f"/api/v1/frames/{ids[1]}/label",
        json=corrected_label(box(30, 70)),
        headers=auth(token),
    ).json()
    assert same["mask_changed"] is False and same["proposal_id"] == second
    wrong = client.put(
        f"/api/v1/frames/{ids[1]}/label",
        json={"status": "accepted", "base_revision": 1, "proposal_id": teacher},
        headers=auth(token),
    )
    assert wrong.status_code == 404 and "no proposal" in wrong.json()["detail"]
    review = client.get("/api/v1/metrics", headers=auth(token)).json()["review"]
    by_source = {s["source"]: s for s in review["by_source"]}
    assert by_source["student:student-v9"]["accepted"] == 1
    assert by_source["student:student-v9"]["acceptance_rate"] == 1.0
    assert by_source["teacher"]["corrected"] == 1 and by_source["teacher"]["unchanged"] == 1
    with session_factory() as session:
        assert session.get_one(Frame, ids[0]).status.value == "accepted"


def test_the_teacher_skips_only_frames_its_own_model_proposed_for(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("skipper", Role.reviewer)
    storage = LocalStorage(settings.home)
    first, second = upload_synthetic(client, token, 2)
    propose(session_factory, storage, first, "student", "student-v3", box(20, 60))
    result = run_teacher(client, token, [first, second])["result"]
    assert result["proposed"] == 2 and result["skipped"] == 0  # a student's proposal is no reason
    again = run_teacher(client, token, [first, second])["result"]
    assert again["proposed"] == 0 and again["skipped"] == 2
    listing = client.get(f"/api/v1/frames/{first}/proposals", headers=auth(token)).json()
    assert [p["source"] for p in listing["items"]] == ["teacher", "student"]
    assert listing["items"][0]["chosen"]  # nothing measured: the teacher's is shown


def test_a_replaced_proposals_files_are_doomed_for_the_collector(
    client: TestClient, make_user, settings, session_factory
) -> None:
    """Propagation replaces a frame's earlier propagated proposal: its mask file is recorded
    for the collector in the same transaction (no listing of the store finds it), and a pass
    after the grace period removes it; the new proposal's file stays."""
    from app.core.housekeeping import collect_doomed
    from app.core.models import DoomedFile
    from app.proposals.record import PROPAGATED, record_proposal
    from tests.helpers import age_stored_files

    _, token = make_user("doomed", Role.reviewer)
    storage = LocalStorage(settings.home)
    (frame_id,) = frame_ids(
        client, token, random_images(numbered(1, first_seed=300), width=W, height=H)
    )
    first = propose(session_factory, storage, frame_id, PROPAGATED, "sam2-video:x", box(10, 40))
    with session_factory() as session:
        old = session.get_one(Proposal, first).mask_path
        frame = session.get_one(Frame, frame_id)
        new = record_proposal(
            session,
            storage,
            frame,
            source=PROPAGATED,
            model_id="sam2-video:x",
            mask=box(20, 60),
            heatmap=None,
            keypoints=[],
            scores={},
            weights={},
            replace_earlier=True,
        ).mask_path
        session.commit()
        assert set(session.scalars(sa.select(DoomedFile.path))) == {old}
        age_stored_files(settings.home, storage.grace_s + 1)
        assert collect_doomed(session, storage) == [old]
    assert not storage.absolute(old).exists() and storage.absolute(new).exists()


def test_the_policy_is_stored_when_a_change_commits_and_read_as_a_row(
    client: TestClient, settings, session_factory, make_user, monkeypatch
) -> None:
    """A label saved through the service measures the policy before its commit and stores it
    (``display_policies``); reads take the row and measure nothing. A change committed where
    the store is unknown leaves the row stale, and the next read measures."""
    from app.core.models import DisplayPolicy
    from app.proposals import policy

    _, token = make_user("stored", Role.reviewer)
    ids = _teacher_and_student(client, token, settings, session_factory, 500, 4)

    def row() -> tuple[bool, str]:
        with session_factory() as session:
            stored = session.get(DisplayPolicy, 1)
            assert stored is not None
            return stored.stale, stored.chosen

    assert row()[0] is True  # written where the store is unknown: stale until measured
    for count, frame_id in enumerate(ids[:3], start=1):
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label",
            json=corrected_label(box(20, 60)),
            headers=auth(token),
        )
        assert saved.status_code == 200, saved.text
        assert row() == (False, "student:student-v1" if count == 3 else "teacher"), count

    def refuse(*_args: object) -> None:
        raise AssertionError("a read measured the policy")

    monkeypatch.setattr(policy, "measure", refuse)
    shown = client.get(f"/api/v1/frames/{ids[3]}/proposal", headers=auth(token)).json()
    assert shown["source_key"] == "student:student-v1"
    listing = client.get(f"/api/v1/frames/{ids[3]}/proposals", headers=auth(token)).json()
    common = {s["key"]: s["common_frames"] for s in listing["policy"]["sources"]}
    assert common == {"teacher": 0, "student:student-v1": 3}

    # A gate verdict written in bulk where the store is unknown: stale; the next read measures.
    with session_factory() as session:
        session.execute(sa.update(ModelVersion).values(gate={"usable": False}))
        session.commit()
    assert row()[0] is True
    monkeypatch.undo()
    shown = client.get(f"/api/v1/frames/{ids[3]}/proposal", headers=auth(token)).json()
    assert shown["source_key"] == "teacher"
