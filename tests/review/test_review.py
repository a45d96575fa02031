"""The review loop through the REST API, on SQLite and PostgreSQL: teacher job, proposal,
click, labels with revisions and history, validation keypoints."""

from __future__ import annotations

import base64
import io
import re
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import run_teacher, upload_synthetic
from tests.helpers import auth, corrected_label, mask_b64, mask_from_b64
from weldpool_core.synth import SynthParams

SIZE = SynthParams(width=160, height=100)


def test_teacher_job_proposes_and_skips_what_it_saw(client: TestClient, people) -> None:
    token = people["reviewer"]
    frame_ids = upload_synthetic(client, token)
    job = run_teacher(client, token, frame_ids)
    assert job["status"] == "succeeded", job
    assert job["result"]["proposed"] == 2 and job["result"]["failed"] == []
    assert job["message"] == "2 frames proposed"  # the jobs page's words, not a progress line
    proposal = client.get(f"/api/v1/frames/{frame_ids[0]}/proposal", headers=auth(token)).json()
    assert mask_from_b64(proposal["mask_png"]).shape == (100, 160)
    assert proposal["source"] == "teacher" and proposal["model_id"] == job["result"]["model_id"]
    # local weights are named by their content, never by this machine's paths or folders
    assert re.fullmatch(
        r"weights#[0-9a-f]{16}@64\+weights#[0-9a-f]{16}\+heuristic", job["result"]["model_id"]
    ), job["result"]["model_id"]
    assert set(proposal["scores"]) >= {"sam2_iou", "object_score"}
    assert proposal["prompts"]["labels"][0] == 1
    frame = client.get(f"/api/v1/frames/{frame_ids[0]}", headers=auth(token)).json()
    assert frame["status"] == "proposed" and frame["proposal"]["id"] == proposal["id"]
    png = client.get(f"/api/v1/frames/{frame_ids[0]}/proposal/mask.png", headers=auth(token))
    assert png.headers["content-type"] == "image/png"
    colour = client.get(f"/api/v1/frames/{frame_ids[0]}/proposal/heatmap.png", headers=auth(token))
    assert cv2.imdecode(np.frombuffer(colour.content, np.uint8), -1).shape == (100, 160, 4)
    raw = client.get(f"/api/v1/frames/{frame_ids[0]}/proposal/heatmap.npy", headers=auth(token))
    heatmap = np.load(io.BytesIO(raw.content))
    assert heatmap.shape == (100, 160, 2)
    assert np.array_equal(heatmap[:, :, 1] > 0.5, mask_from_b64(proposal["mask_png"]))

    again = run_teacher(client, token, frame_ids)
    assert (again["result"]["proposed"], again["result"]["skipped"]) == (0, 2)
    assert again["message"] == (
        "0 frames proposed; 2 skipped (this teacher proposed them before; run with force to redo)"
    )


def test_click_uses_the_cached_embedding(client: TestClient, people) -> None:
    token = people["reviewer"]
    frame_id = upload_synthetic(client, token, 1)[0]
    first = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={"points": [{"x": 80, "y": 50, "positive": True}]},
        headers=auth(token),
    )
    assert first.status_code == 200, first.text
    assert first.json()["embedding"] == "computed"
    second = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={
            "points": [{"x": 80, "y": 50}, {"x": 5, "y": 5, "positive": False}],
            "box": [20, 10, 150, 90],
            "mask_png": first.json()["mask_png"],
        },
        headers=auth(token),
    ).json()
    assert second["embedding"] == "memory" and second["elapsed_ms"] > 0
    assert mask_from_b64(second["mask_png"]).shape == (100, 160)
    outside = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={"points": [{"x": 500, "y": 50}]},
        headers=auth(token),
    )
    assert outside.status_code == 400 and "outside" in outside.json()["detail"]
    empty = client.post(f"/api/v1/frames/{frame_id}/segment", json={}, headers=auth(token))
    assert empty.status_code == 400


def test_one_failing_frame_does_not_end_the_teacher_run(
    client: TestClient, people, monkeypatch
) -> None:
    """A RuntimeError on one frame is recorded on that frame; the other frames get proposals;
    the next good run clears the record. A run where every frame fails is a failed job."""
    from weldpool_core.teacher.teacher import Teacher

    token = people["reviewer"]
    frame_ids = upload_synthetic(client, token, 3)
    bad = client.get(f"/api/v1/frames/{frame_ids[1]}", headers=auth(token)).json()["sha256"]
    real_run = Teacher.run

    def run(self, image, key=None, *args, **kwargs):  # type: ignore[no-untyped-def]
        if key == bad:
            raise RuntimeError("CUDA error: an illegal memory access was encountered")
        return real_run(self, image, key, *args, **kwargs)

    monkeypatch.setattr(Teacher, "run", run)
    job = run_teacher(client, token, frame_ids)
    assert job["status"] == "succeeded"
    assert job["result"]["proposed"] == 2
    assert job["result"]["failed"] == [
        {
            "frame_id": frame_ids[1],
            "error": "Unexpected error (RuntimeError): CUDA error: an illegal memory access was "
            "encountered",
        }
    ]
    frames = {f["id"]: f for f in client.get("/api/v1/frames", headers=auth(token)).json()["items"]}
    assert frames[frame_ids[1]]["teacher_error"].startswith("Unexpected error (RuntimeError)")
    assert frames[frame_ids[0]]["teacher_error"] is None
    assert [frames[i]["status"] for i in frame_ids] == ["proposed", "new", "proposed"]

    only_bad = run_teacher(client, token, [frame_ids[1]])
    assert only_bad["status"] == "failed" and "failed on every frame" in only_bad["error"]
    monkeypatch.undo()
    again = run_teacher(client, token, [frame_ids[1]])
    assert again["status"] == "succeeded" and again["result"]["proposed"] == 1
    frame = client.get(f"/api/v1/frames/{frame_ids[1]}", headers=auth(token)).json()
    assert frame["teacher_error"] is None


def test_cancel_stops_the_teacher_inside_a_frame(
    client: TestClient, people, monkeypatch, session_factory
) -> None:
    """A cancel asked for while a frame is being proposed ends the job after the stage that
    is running (not after the frame, nor the run), as cancelled: no proposal, no frame error."""
    import sqlalchemy as sa

    from app.core.models import Job
    from weldpool_core.teacher.teacher import Teacher

    token = people["reviewer"]
    frame_ids = upload_synthetic(client, token, 2)
    real_run = Teacher.run
    seen = []

    def run(self, image, key=None, between=None):  # type: ignore[no-untyped-def]
        seen.append(key)
        with session_factory() as session:  # the user presses Cancel during the first frame
            session.execute(sa.update(Job).values(cancel_requested=True))
            session.commit()
        return real_run(self, image, key, between=between)

    monkeypatch.setattr(Teacher, "run", run)
    job = run_teacher(client, token, frame_ids)
    assert job["status"] == "cancelled"
    assert len(seen) == 1  # the second frame never started
    frames = client.get("/api/v1/frames", headers=auth(token)).json()["items"]
    assert {f["status"] for f in frames if f["id"] in frame_ids} == {"new"}
    assert all(f["teacher_error"] is None for f in frames)


def _artefact_masks(client: TestClient) -> set[str]:
    home = client.app.state.storage.home
    return {p.name for p in (home / "artefacts").rglob("*.png")}


def test_a_refused_label_save_writes_no_mask_file(client: TestClient, people, monkeypatch) -> None:
    """A stale save (409) is refused before its mask is written; a save that loses the race
    after writing (two first labels at once) removes the file it wrote."""
    import app.review.service as review_service

    rita = people["reviewer"]
    frame_id = upload_synthetic(client, rita, 1)[0]
    url = f"/api/v1/frames/{frame_id}/label"
    first_mask = np.zeros((100, 160), bool)
    first_mask[20:80, 30:130] = True
    assert client.put(url, json=corrected_label(first_mask), headers=auth(rita)).status_code == 200
    before = _artefact_masks(client)

    other = np.zeros((100, 160), bool)
    other[10:50, 10:60] = True
    stale = client.put(url, json=corrected_label(other, base_revision=0), headers=auth(rita))
    assert stale.status_code == 409
    assert _artefact_masks(client) == before

    # The race: the revision check saw no label, the insert then finds one.
    monkeypatch.setattr(review_service, "current_label", lambda session, frame_id: None)
    lost = client.put(url, json=corrected_label(other, base_revision=0), headers=auth(rita))
    assert lost.status_code == 409 and lost.json()["revision"] == 1
    assert _artefact_masks(client) == before
    monkeypatch.undo()
    # The same content saved for real is stored and kept.
    kept = client.put(url, json=corrected_label(other, base_revision=1), headers=auth(rita))
    assert kept.status_code == 200 and len(_artefact_masks(client)) == len(before) + 1


def test_labels_revisions_conflicts_and_history(client: TestClient, people) -> None:
    rita, otto, anna = people["reviewer"], people["other"], people["annotator"]
    frame_id = upload_synthetic(client, rita, 1)[0]
    url = f"/api/v1/frames/{frame_id}/label"
    nothing = client.put(url, json={"status": "accepted", "base_revision": 0}, headers=auth(rita))
    assert nothing.status_code == 400 and "no proposal" in nothing.json()["detail"]
    run_teacher(client, rita, [frame_id])

    forbidden = client.put(url, json={"status": "accepted", "base_revision": 0}, headers=auth(anna))
    assert forbidden.status_code == 403
    accepted = client.put(url, json={"status": "accepted", "base_revision": 0}, headers=auth(rita))
    assert accepted.status_code == 200 and accepted.json()["revision"] == 1

    # Both reviewers saw revision 1; Rita corrects first, Otto's stale write is refused.
    mask = np.zeros((100, 160), bool)
    mask[20:80, 30:130] = True
    corrected = corrected_label(mask, base_revision=1)
    first = client.put(url, json=corrected, headers=auth(rita))
    assert first.status_code == 200 and first.json()["revision"] == 2
    assert len(first.json()["keypoints"]) == 4  # recomputed by Algorithm 1
    stale = client.put(url, json={"status": "rejected", "base_revision": 1}, headers=auth(otto))
    assert stale.status_code == 409
    assert stale.json()["revision"] == 2 and stale.json()["updated_by"] == "rita"
    assert stale.json()["detail"].startswith("The label was changed by rita (now at revision 2)")
    overwrite = client.put(url, json={"status": "rejected", "base_revision": 2}, headers=auth(otto))
    assert overwrite.json() == overwrite.json() | {
        "revision": 3,
        "status": "rejected",
        "mask_png": None,
        "updated_by": "otto",
    }
    by_annotator = client.put(
        url,
        json={
            "status": "corrected",
            "base_revision": 3,
            "keypoints": [[40, 30], [120, 30], [120, 70], [40, 70]],
            "mask_png": corrected["mask_png"],
        },
        headers=auth(anna),
    )
    assert by_annotator.status_code == 200 and by_annotator.json()["keypoints"][0] == [40, 30]

    history = client.get(f"{url}/history", headers=auth(rita)).json()
    assert [(h["revision"], h["status"], h["user"]) for h in history] == [
        (1, "accepted", "rita"),
        (2, "corrected", "rita"),
        (3, "rejected", "otto"),
        (4, "corrected", "anna"),
    ]
    current = client.get(url, headers=auth(rita)).json()
    assert current["revision"] == 4 and np.array_equal(mask_from_b64(current["mask_png"]), mask)
    assert (
        client.get(f"/api/v1/frames/{frame_id}", headers=auth(rita)).json()["status"] == "corrected"
    )


def test_bad_label_input(client: TestClient, people) -> None:
    token = people["reviewer"]
    frame_id = upload_synthetic(client, token, 1)[0]
    url = f"/api/v1/frames/{frame_id}/label"
    small = mask_b64(np.ones((10, 10), bool))
    wrong_size = client.put(
        url,
        json={"status": "corrected", "base_revision": 0, "mask_png": small},
        headers=auth(token),
    )
    assert wrong_size.status_code == 400 and "10×10" in wrong_size.json()["detail"]
    garbage = client.put(
        url,
        json={"status": "corrected", "base_revision": 0, "mask_png": "not base64!"},
        headers=auth(token),
    )
    assert garbage.status_code == 400
    no_change = client.put(
        url, json={"status": "corrected", "base_revision": 0}, headers=auth(token)
    )
    assert no_change.status_code == 422
    assert client.get(url, headers=auth(token)).status_code == 404


def test_validation_keypoints_move_the_frame(client: TestClient, people) -> None:
    token = people["annotator"]
    frame_id = upload_synthetic(client, token, 1)[0]
    url = f"/api/v1/frames/{frame_id}/validation-keypoints"
    points = [[30.5, 40.0], [100.0, 20.0], [140.0, 60.0], [60.0, 90.0]]
    saved = client.put(url, json={"keypoints": points}, headers=auth(token))
    assert saved.status_code == 200 and saved.json()["keypoints"] == points
    frame = client.get(f"/api/v1/frames/{frame_id}", headers=auth(token)).json()
    assert frame["split"] == "validation" and frame["has_validation_keypoints"] is True
    assert client.get(url, headers=auth(token)).json()["keypoints"] == points
    outside = client.put(url, json={"keypoints": [[999, 1]]}, headers=auth(token))
    assert outside.status_code == 400


def test_validation_keypoints_saved_from_a_stale_revision_are_a_409_naming_who(
    client: TestClient, people
) -> None:
    """Each save moves the revision on; a save from an older one is refused with the current
    revision and its author, and nothing is written; from the current one, or with no base
    (the API's older callers), it replaces them."""
    annotator, reviewer = people["annotator"], people["reviewer"]
    frame_id = upload_synthetic(client, annotator, 1)[0]
    url = f"/api/v1/frames/{frame_id}/validation-keypoints"

    def put(token: str, x: float, base: int | None) -> Any:
        body: dict[str, Any] = {"keypoints": [[x, 20.0]]}
        if base is not None:
            body["base_revision"] = base
        return client.put(url, json=body, headers=auth(token))

    first = put(annotator, 10.0, 0)
    assert first.status_code == 200 and first.json()["revision"] == 1
    assert put(reviewer, 11.0, 1).json()["revision"] == 2
    stale = put(annotator, 12.0, 1)
    assert stale.status_code == 409
    assert stale.json()["revision"] == 2 and stale.json()["updated_by"] == "rita"
    assert stale.json()["detail"] == (
        "The validation keypoints were changed by rita (now at revision 2); reload them and "
        "apply your change again, or overwrite with base_revision 2."
    )
    assert put(annotator, 13.0, 0).status_code == 409  # "the first ones": there are some
    assert client.get(url, headers=auth(annotator)).json() | {"updated_at": None} == {
        "frame_id": frame_id,
        "keypoints": [[11.0, 20.0]],
        "revision": 2,
        "updated_at": None,
    }
    assert put(annotator, 14.0, 2).json()["revision"] == 3
    assert put(reviewer, 15.0, None).json()["revision"] == 4


def test_missing_weights_fail_the_job_at_once(settings, session_factory, make_user, tmp_path):
    from app.main import create_app
    from app.system.status import sam2_problem, teacher_problem

    broken = settings.model_copy(update={"dino": str(tmp_path / "no-dino")})
    _, token = make_user("weightless", Role.reviewer)
    with TestClient(create_app(broken, embedded_worker=True)) as client:
        frame_ids = upload_synthetic(client, token, 1)
        job = run_teacher(client, token, frame_ids)
        assert job["status"] == "failed"
        assert "WELDPOOL_DINO" in job["error"] and job["error"].endswith(".")
        health = client.get("/api/v1/health").json()  # usable, and it says what is missing
        assert health["status"] == "degraded" and "WELDPOOL_DINO" in health["warnings"][0]
        # Clicks and boxes need SAM2 only: they stay usable without DINO, and say so without SAM2.
        assert sam2_problem(broken) is None
        assert "WELDPOOL_SAM2" not in str(teacher_problem(broken))
        no_sam2 = settings.model_copy(update={"sam2": str(tmp_path / "no-sam2")})
        assert str(sam2_problem(no_sam2)).startswith(
            "Clicks, boxes and propagation need SAM2: its weights are missing (WELDPOOL_SAM2)."
        )
        assert (
            client.get(f"/api/v1/frames/{frame_ids[0]}/proposal", headers=auth(token)).status_code
            == 404
        )


def test_outline_round_trip_through_the_api(client: TestClient, people) -> None:
    """The polygon tool's two calls: trace a mask of the frame, fill an edited outline back."""
    token = people["annotator"]
    (frame_id,) = upload_synthetic(client, token, 1)
    mask = np.zeros((100, 160), np.uint8)
    mask[20:61, 30:91] = 1
    mask[35:45, 50:70] = 0  # a hole

    def trace(tolerance: float) -> list[dict]:
        body = {"mask_png": mask_b64(mask), "tolerance": tolerance}
        traced = client.post(f"/api/v1/frames/{frame_id}/outline", json=body, headers=auth(token))
        assert traced.status_code == 200, traced.text
        return traced.json()["polygons"]

    exact = trace(0)
    assert [p["hole"] for p in exact] == [False, True]
    filled = client.post(
        f"/api/v1/frames/{frame_id}/outline/mask", json={"polygons": exact}, headers=auth(token)
    )
    assert filled.status_code == 200, filled.text
    assert np.array_equal(mask_from_b64(filled.json()["mask_png"]), mask.astype(bool))
    assert filled.json()["area"] == int(mask.sum())
    polygons = trace(1.0)  # the tool's default: a rectangle is its four corners
    assert sorted(map(tuple, polygons[0]["points"])) == [(30, 20), (30, 60), (90, 20), (90, 60)]
    before = client.post(
        f"/api/v1/frames/{frame_id}/outline/mask", json={"polygons": polygons}, headers=auth(token)
    ).json()["area"]
    # Drag the bottom-right corner 20 px right: the area grows by the swept triangle (40·20/2).
    polygons[0]["points"] = [[110, 60] if p == [90, 60] else p for p in polygons[0]["points"]]
    moved = client.post(
        f"/api/v1/frames/{frame_id}/outline/mask", json={"polygons": polygons}, headers=auth(token)
    )
    assert moved.json()["area"] - before == pytest.approx(400, abs=25)
    # Bad input: a mask of another size, a polygon of two vertices; each a one-sentence 4xx.
    wrong = client.post(
        f"/api/v1/frames/{frame_id}/outline",
        json={"mask_png": mask_b64(np.zeros((10, 10), np.uint8))},
        headers=auth(token),
    )
    assert (
        wrong.status_code == 400
        and wrong.json()["detail"] == "The mask must have the frame's size."
    )
    short = client.post(
        f"/api/v1/frames/{frame_id}/outline/mask",
        json={"polygons": [{"points": [[0, 0], [5, 5]]}]},
        headers=auth(token),
    )
    assert short.status_code == 422


def test_a_mask_of_faint_values_is_refused_naming_the_levels(client: TestClient, people) -> None:
    """A mask whose pool is drawn at 77 has no pixel at or above 128: the refusal says which
    values are pool (it only said the mask was empty), and nothing is stored."""
    token = people["annotator"]
    frame_id = upload_synthetic(client, token, 1)[0]
    frame = client.get(f"/api/v1/frames/{frame_id}", headers=auth(token)).json()
    faint = np.zeros((frame["height"], frame["width"]), np.uint8)
    faint[10:40, 20:60] = 77
    body = {
        "status": "corrected",
        "base_revision": 0,
        "mask_png": base64.b64encode(cv2.imencode(".png", faint)[1].tobytes()).decode(),
    }
    refused = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
    assert refused.status_code == 400
    assert refused.json()["detail"] == (
        "The mask is empty (pool pixels are 255, or 1 in a mask of 0 and 1; values under 128 "
        "are outside); reject the frame if it shows no pool."
    )
    assert client.get(f"/api/v1/frames/{frame_id}/label", headers=auth(token)).status_code == 404
