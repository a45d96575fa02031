"""The promotion gate (``app.training.gate``): a worse student is never promoted.

Student versions here are real checkpoints (a light student trained briefly on synthetic
frames) whose output heads are then biased on purpose: mask bias −30 draws no pool (mIoU 0),
+30 draws the whole frame; heatmap bias −30 finds no keypoint. The reviewed masks and the
teacher's proposals are set so each case has one known answer.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from safetensors.torch import load_file, save_file

from app.core.models import Frame, ModelVersion, Proposal, Role
from app.proposals.files import store_mask
from app.storage import LocalStorage
from app.training import gate
from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
from tests.factories import frame_ids, numbered, random_images
from tests.helpers import auth, corrected_label, wait_for_job
from tests.proposals.common import H, W, box, propose
from weldpool_core.student.train import train_student

KEYPOINTS = [[20.0, 20.0], [76.0, 20.0], [76.0, 44.0], [20.0, 44.0]]


@pytest.fixture(scope="module")
def base_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A student whose keypoints are its heatmap's peaks, so that the head's biases below make
    its mask and its keypoints separately (from the mask, a whole-frame pool has corners)."""
    out = tmp_path_factory.mktemp("gate") / "model"
    student = replace(TINY_STUDENT, keypoints="heatmap")
    train_student(synthetic_frames(4), out, student, tiny_config(epochs=1))
    return out


def _version(
    settings,
    session_factory,
    base: Path,
    name: str,
    mask_bias: float,
    heat_bias: float,
    held_out: list[int],
    promoted: bool = False,
) -> int:
    folder = Path(settings.home) / "models" / name
    shutil.copytree(base, folder)
    weights = load_file(str(folder / "model.safetensors"))
    weights["decoder.head.bias"][0] = mask_bias
    weights["decoder.head.bias"][1] = heat_bias
    save_file(weights, str(folder / "model.safetensors"))
    with session_factory() as session:
        version = ModelVersion(
            name=name,
            checkpoint_path=f"models/{name}",
            train_frame_ids=[],
            held_out_frame_ids=held_out,
            is_promoted=promoted,
        )
        session.add(version)
        session.commit()
        return version.id


def _truth() -> np.ndarray:
    mask = np.ones((H, W), bool)
    mask[:2], mask[-2:], mask[:, :2], mask[:, -2:] = False, False, False, False
    return mask  # what a whole-frame mask gets IoU 0.90 on


def _shrunk() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[8:56, 10:86] = True  # IoU 0.66 with the truth
    return mask


def _frames_with_labels(client, token, settings, session_factory, teacher_keypoints) -> list[int]:
    ids = frame_ids(client, token, random_images(numbered(3, first_seed=300), width=W, height=H))
    storage = LocalStorage(settings.home)
    with session_factory() as session:
        for frame_id in ids:
            session.add(
                Proposal(
                    frame_id=frame_id,
                    source="teacher",
                    model_id="teacher-under-test",
                    mask_path=store_mask(storage, _shrunk()),
                    keypoints=teacher_keypoints,
                )
            )
        session.commit()
    for frame_id in ids:
        body = corrected_label(_truth()) | {"keypoints": KEYPOINTS}
        response = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert response.status_code == 200, response.text
    return ids


def _measure(settings, session_factory, candidate: int, incumbent: int | None = None) -> dict:
    with session_factory() as session:
        return gate.measure(
            session,
            LocalStorage(settings.home),
            session.get_one(ModelVersion, candidate),
            session.get(ModelVersion, incumbent) if incumbent else None,
            "cpu",
        )


def test_a_student_with_no_pool_or_no_keypoints_is_not_promoted_and_the_teacher_stays(
    client: TestClient, settings, session_factory, make_user, base_model: Path
) -> None:
    _, token = make_user("gatekeeper", Role.reviewer)
    shifted = [[x + 6.0, y] for x, y in KEYPOINTS]  # the teacher: mIoU 0.66, keypoints 6 px off
    ids = _frames_with_labels(client, token, settings, session_factory, shifted)

    empty = _version(settings, session_factory, base_model, "empty", -30.0, 0.0, ids)
    verdict = _measure(settings, session_factory, empty)
    assert verdict["candidate"]["mIoU"] == 0.0 and verdict["frames"] == ids
    assert verdict["teacher"]["mIoU"] == pytest.approx(48 * 76 / (60 * 92))
    assert not verdict["usable"] and not verdict["promote"]
    assert "worse than the teacher" in verdict["reason"]

    blind = _version(settings, session_factory, base_model, "blind", 30.0, -30.0, ids)
    verdict = _measure(settings, session_factory, blind)
    assert verdict["candidate"]["mIoU"] > verdict["teacher"]["mIoU"]  # a better mask …
    assert verdict["candidate"]["missed"] == 12  # … but no keypoint at all
    assert verdict["candidate"]["mED_penalised"] == pytest.approx(np.hypot(W, H))
    assert verdict["teacher"]["mED_penalised"] == pytest.approx(6.0)
    assert not verdict["usable"]

    refused = client.post(f"/api/v1/models/{empty}/promote", headers=auth(token))
    assert refused.status_code == 409 and "teacher" in refused.json()["detail"]
    assert refused.json()["reason"].startswith("worse than the teacher")  # the page's words
    models = {m["name"]: m for m in client.get("/api/v1/models", headers=auth(token)).json()}
    assert not models["empty"]["is_promoted"] and models["empty"]["gate"]["usable"] is False
    proposal = client.get(f"/api/v1/frames/{ids[0]}/proposal", headers=auth(token)).json()
    assert proposal["source"] == "teacher" and proposal["chosen"]

    forced = client.post(f"/api/v1/models/{empty}/promote?force=true", headers=auth(token))
    assert forced.status_code == 200 and forced.json()["is_promoted"]


def test_a_usable_first_version_is_promoted_and_an_equal_one_is_not(
    client: TestClient, settings, session_factory, make_user, base_model: Path
) -> None:
    _, token = make_user("gatekeeper2", Role.reviewer)
    ids = _frames_with_labels(client, token, settings, session_factory, [])  # teacher: no keypoints
    whole = _version(settings, session_factory, base_model, "whole", 30.0, -30.0, ids)
    verdict = _measure(settings, session_factory, whole)
    assert verdict["usable"] and verdict["promote"], verdict["reason"]  # better mask, same misses

    twin = _version(settings, session_factory, base_model, "twin", 30.0, -30.0, ids)
    verdict = _measure(settings, session_factory, twin, incumbent=whole)
    assert verdict["usable"] and not verdict["promote"]
    assert "not better than whole" in verdict["reason"]
    assert verdict["incumbent_scores"]["mIoU"] == verdict["candidate"]["mIoU"]

    empty = _version(settings, session_factory, base_model, "empty2", -30.0, 0.0, ids)
    assert not _measure(settings, session_factory, empty, incumbent=whole)["promote"]

    trained_on = _version(settings, session_factory, base_model, "trained-on", 30.0, -30.0, ids)
    with session_factory() as session:
        session.get_one(ModelVersion, trained_on).train_frame_ids = ids
        session.commit()
    verdict = _measure(settings, session_factory, trained_on)
    assert verdict["frames"] == [] and not verdict["usable"]  # never judged on its own training


def test_pseudo_labels_are_confident_teacher_proposals_on_unlabelled_frames_only(
    client: TestClient, settings, session_factory, make_user
) -> None:
    from app.core.models import Split
    from app.training.service import pseudo_label_proposals, teacher_confidence

    _, token = make_user("distiller", Role.reviewer)
    storage = LocalStorage(settings.home)
    ids = frame_ids(client, token, random_images(numbered(5, first_seed=600), width=W, height=H))
    sure, unsure, student_only, labelled, validation = ids
    with session_factory() as session:
        for frame_id, iou, stability in [
            (sure, 0.95, 0.95),
            (unsure, 0.95, 0.5),
            (labelled, 0.99, 0.99),
            (validation, 0.99, 0.99),
        ]:
            session.add(
                Proposal(
                    frame_id=frame_id,
                    source="teacher",
                    model_id="t",
                    mask_path=store_mask(storage, box(20, 60)),
                    scores={"sam2_iou": iou, "prompt_stability": stability},
                )
            )
        session.add(
            Proposal(
                frame_id=student_only,
                source="student",
                model_id="student-v1",
                mask_path=store_mask(storage, box(20, 60)),
                scores={"sam2_iou": 1.0, "prompt_stability": 1.0},
            )
        )
        session.get_one(Frame, validation).split = Split.validation
        session.commit()
    client.put(
        f"/api/v1/frames/{labelled}/label", json=corrected_label(box(20, 60)), headers=auth(token)
    )
    with session_factory() as session:
        chosen = pseudo_label_proposals(session, 0.8)
        assert [(p.frame_id, round(c, 4)) for p, c in chosen] == [(sure, 0.9025)]
        assert [p.frame_id for p, _ in pseudo_label_proposals(session, 0.4)] == [sure, unsure]
    job = client.post(
        "/api/v1/student/train",
        json={"epochs": 1, "size": "light", "pseudo_labels": True},
        headers=auth(token),
    ).json()
    done = wait_for_job(client, job["job_id"], token, timeout=300)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["metrics"]["pseudo_labels"] == 1
    # The job's last word is the version it kept and the gate's verdict, not the last epoch.
    name = done["result"]["name"]
    assert re.fullmatch(rf"{name} keeps round 1 of 1 \(mIoU \d\.\d{{3}}.*\); .+", done["message"])
    with session_factory() as session:
        version = session.get_one(ModelVersion, done["result"]["model_version_id"])
        assert version.train_frame_ids == [labelled, sure] and version.train_label_count == 1
    assert teacher_confidence({"sam2_iou": 0.5}) == 0.5
    assert teacher_confidence({"sam2_iou": 0.5, "prompt_stability": 0.5}) == 0.25
    assert teacher_confidence({}) is None


def test_the_train_job_says_which_round_it_kept_and_the_verdict() -> None:
    from app.training.tasks import _summary

    metrics = {"mIoU": 0.87444444, "mED": 11.4444}
    no = {"promote": False, "reason": "Worse than the teacher on 4 frames."}
    assert (
        _summary("student-v3", 3, 5, metrics, no, False) == "student-v3 keeps round 3 of 5 "
        "(mIoU 0.874, mED 11.4 px); not promoted: Worse than the teacher on 4 frames."
    )
    gate = {"promote": False, "reason": "Not promoted: worse than the teacher on 4 frames."}
    assert _summary("v", 1, 1, metrics, gate, False).endswith(
        "; not promoted: worse than the teacher on 4 frames."
    )  # the gate's own "Not promoted: " is not said twice
    yes = {"promote": True, "reason": ""}
    assert _summary("v", 5, 5, {"mIoU": 0.5, "mED": None}, yes, True).endswith(
        "(mIoU 0.500); promoted"
    )
    assert "promote it on the models page" in _summary("v", 1, 1, metrics, yes, False)


def _big() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[4:60, 4:92] = True  # IoU 0.80 with a whole-frame mask
    return mask


def test_labels_accepted_from_the_teacher_do_not_decide_against_a_better_student(
    client: TestClient, settings, session_factory, make_user, base_model: Path
) -> None:
    """Four held-out labels were accepted unchanged from the teacher (its mIoU there: 1.000),
    two were drawn by hand, where the teacher is far off (0.66) and the student close (0.90).
    Over all six the teacher wins (0.89 vs 0.83); on the drawn labels, the fair yardstick, the
    student does, and on the accepted ones it is near enough (0.80 ≥ MIN_MIOU): promoted."""
    _, token = make_user("fair", Role.reviewer)
    storage = LocalStorage(settings.home)
    ids = frame_ids(client, token, random_images(numbered(6, first_seed=500), width=W, height=H))
    accepted = ids[:4]
    for frame_id in ids:
        mask = _big() if frame_id in accepted else _shrunk()
        proposal = propose(session_factory, storage, frame_id, "teacher", "teacher-t", mask)
        body = (
            {"status": "accepted", "base_revision": 0, "proposal_id": proposal}
            if frame_id in accepted
            else corrected_label(_truth())
        )
        saved = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
    whole = _version(settings, session_factory, base_model, "fair-whole", 30.0, -30.0, ids)
    verdict = _measure(settings, session_factory, whole)
    assert verdict["usable"] and verdict["promote"], verdict["reason"]
    assert verdict["accepted_from_teacher"] == accepted
    assert verdict["reason"].startswith("Better than the teacher on 6 held-out frames")
    assert verdict["teacher"]["mIoU"] == pytest.approx(48 * 76 / (60 * 92))  # drawn ones only
    assert verdict["teacher"]["candidate_on_these"]["mIoU"] == pytest.approx(60 * 92 / (H * W))

    # The floor holds: a student far off where the teacher was accepted is not usable.
    for frame_id in accepted:  # the labels accepted the small box instead
        current = client.get(f"/api/v1/frames/{frame_id}/label", headers=auth(token)).json()
        proposal = propose(session_factory, storage, frame_id, "teacher", "teacher-t", box(40, 56))
        body = {"status": "accepted", "base_revision": current["revision"], "proposal_id": proposal}
        saved = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
    verdict = _measure(settings, session_factory, whole)
    assert not verdict["usable"] and "accepted from the teacher unchanged" in verdict["reason"]


def test_an_incumbent_is_not_judged_on_labels_taken_from_its_own_proposals(
    client: TestClient, settings, session_factory, make_user, base_model: Path
) -> None:
    """Every held-out label was accepted unchanged from the promoted version's proposals: it
    would score 1.000 there, so the gate refuses to compare on them and says what to do."""
    _, token = make_user("fair2", Role.reviewer)
    storage = LocalStorage(settings.home)
    ids = frame_ids(client, token, random_images(numbered(3, first_seed=600), width=W, height=H))
    incumbent = _version(settings, session_factory, base_model, "inc", 30.0, -30.0, ids, True)
    for frame_id in ids:
        with session_factory() as session:
            proposal = Proposal(
                frame_id=frame_id,
                source="student",
                model_id="inc",
                model_version_id=incumbent,
                mask_path=store_mask(storage, _truth()),
                keypoints=[],
            )
            session.add(proposal)
            session.commit()
            body = {"status": "accepted", "base_revision": 0, "proposal_id": proposal.id}
        saved = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
    candidate = _version(settings, session_factory, base_model, "cand", 30.0, -30.0, ids)
    verdict = _measure(settings, session_factory, candidate, incumbent=incumbent)
    assert verdict["usable"] and not verdict["promote"]
    assert "cannot be compared fairly" in verdict["reason"]
    assert "incumbent_scores" not in verdict
