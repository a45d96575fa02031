"""Propagation through a weld run with the tiny random SAM2 video model: a job writing one
propagated proposal per frame, replacing earlier ones downstream, cancelled cleanly."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Job, Proposal, Role
from tests.factories import frame_ids
from tests.helpers import auth, corrected_label, wait_for_job
from weldpool_core.synth import SynthParams, synth_frame

SIZE = SynthParams(width=96, height=64)


def _run(
    client: TestClient, token: str, count: int = 6, name: str = "Run"
) -> tuple[int, list[int], list]:
    sequence = client.post("/api/v1/sequences", json={"name": name}, headers=auth(token)).json()
    frames = [synth_frame(seed=300 + i, params=SIZE) for i in range(count)]
    files = [
        (f"f{i:03d}.png", cv2.imencode(".png", f.image)[1].tobytes()) for i, f in enumerate(frames)
    ]
    ids = frame_ids(client, token, files, sequence_id=sequence["id"])
    return sequence["id"], ids, frames


def _propagated(session_factory) -> dict[int, list[Proposal]]:
    with session_factory() as session:
        rows = session.scalars(sa.select(Proposal).where(Proposal.source == "propagated")).all()
        out: dict[int, list[Proposal]] = {}
        for row in rows:
            out.setdefault(row.frame_id, []).append(row)
        return out


def test_propagate_from_a_reviewed_frame_then_again_downstream(
    client: TestClient, make_user, session_factory
) -> None:
    _, token = make_user("propagator", Role.reviewer)
    sequence_id, ids, frames = _run(client, token)
    for index in (2, 4):
        saved = client.put(
            f"/api/v1/frames/{ids[index]}/label",
            json=corrected_label(frames[index].mask),
            headers=auth(token),
        )
        assert saved.status_code == 200
    started = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[2]]},
        headers=auth(token),
    )
    assert started.status_code == 202, started.text
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["proposed"] == 5
    first = _propagated(session_factory)
    assert sorted(first) == [ids[i] for i in (0, 1, 3, 4, 5)]  # every frame but the prompt
    for frame_id, (proposal,) in first.items():
        assert proposal.scores["from_frame_id"] == ids[2]
        assert 0.0 <= proposal.scores["confidence"] <= 1.0
        assert proposal.model_id.startswith("sam2-video:")
        # the job rescored the frame: SAM2's doubt is in the queue's score
        detail = client.get(f"/api/v1/frames/{frame_id}", headers=auth(token)).json()
        doubt = detail["uncertainty_components"]["propagation_doubt"]
        assert doubt == pytest.approx(1 - proposal.scores["confidence"], abs=1e-6)
    listed = client.get(f"/api/v1/frames/{ids[5]}/proposals", headers=auth(token)).json()
    assert [p["source"] for p in listed["items"]] == ["propagated"]
    timeline = client.get(f"/api/v1/sequences/{sequence_id}/geometry", headers=auth(token)).json()
    sources = [row["source"] for row in timeline["frames"]]
    assert sources[2] == "label" and sources[5].startswith("propagated:")

    # A reviewer accepts frame 5's propagated mask: the label records that proposal.
    kept = first[ids[5]][0].id
    accepted = client.put(
        f"/api/v1/frames/{ids[5]}/label",
        json={"status": "accepted", "base_revision": 0, "proposal_id": kept},
        headers=auth(token),
    )
    assert accepted.status_code == 200 and accepted.json()["proposal_id"] == kept

    # Again from frame 4, forward: frames after it are replaced, the ones before are kept.
    again = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[4]], "direction": "forward"},
        headers=auth(token),
    )
    assert wait_for_job(client, again.json()["job_id"], token, timeout=300)["status"] == "succeeded"
    second = _propagated(session_factory)
    assert all(len(items) == 1 for frame, items in second.items() if frame != ids[5])
    newest = max(second[ids[5]], key=lambda p: p.id)
    assert newest.scores["from_frame_id"] == ids[4]
    # … except the proposal a label started from: kept, and the label still names it.
    assert kept in {p.id for p in second[ids[5]]}
    label = client.get(f"/api/v1/frames/{ids[5]}/label", headers=auth(token)).json()
    assert label["proposal_id"] == kept
    assert second[ids[1]][0].id == first[ids[1]][0].id  # upstream: untouched

    # Bad starts are refused in one sentence, before any job.
    no_label = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[0]]},
        headers=auth(token),
    )
    assert no_label.status_code == 400 and "no reviewed mask" in no_label.json()["detail"]
    other, _, _ = _run(client, token, 1, "Another run")
    foreign = client.post(
        f"/api/v1/sequences/{other}/propagate",
        json={"from_frame_ids": [ids[2]]},
        headers=auth(token),
    )
    assert foreign.status_code == 400 and "not a frame of weld run" in foreign.json()["detail"]
    missing = client.post(
        "/api/v1/sequences/999999/propagate", json={"from_frame_ids": [ids[2]]}, headers=auth(token)
    )
    assert missing.status_code == 404


def test_a_cancelled_propagation_leaves_whole_proposals_only(
    client: TestClient, make_user, session_factory, settings, monkeypatch
) -> None:
    from app.review import propagation

    _, token = make_user("canceller", Role.reviewer)
    sequence_id, ids, frames = _run(client, token)
    client.put(
        f"/api/v1/frames/{ids[0]}/label", json=corrected_label(frames[0].mask), headers=auth(token)
    )
    real_record = propagation.record

    def record(session, *args, **kwargs):  # type: ignore[no-untyped-def]
        proposal = real_record(session, *args, **kwargs)
        session.execute(sa.update(Job).values(cancel_requested=True))  # Cancel, pressed now
        session.commit()
        return proposal

    monkeypatch.setattr(propagation, "record", record)
    started = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[0]], "direction": "forward"},
        headers=auth(token),
    )
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "cancelled"
    written = _propagated(session_factory)
    assert list(written) == [ids[1]]  # the frame it was on, whole; nothing after it
    (proposal,) = written[ids[1]]
    assert (settings.home / proposal.mask_path).is_file()
    assert proposal.keypoints is not None and "confidence" in proposal.scores


@pytest.mark.parametrize("threshold", [1.0])
def test_a_pass_stops_where_confidence_stays_low(
    client: TestClient, make_user, session_factory, threshold: float
) -> None:
    """With a threshold no frame reaches, the pass stops after three flagged frames and says
    where (the reviewer prompts again there)."""
    _, token = make_user("stopper", Role.reviewer)
    sequence_id, ids, frames = _run(client, token, 7)
    client.put(
        f"/api/v1/frames/{ids[0]}/label", json=corrected_label(frames[0].mask), headers=auth(token)
    )
    started = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[0]], "direction": "forward", "threshold": threshold},
        headers=auth(token),
    )
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded"
    assert job["result"]["proposed"] == 3
    assert job["result"]["low_confidence_frame_ids"] == ids[1:4]
    assert job["result"]["stopped"] == [
        {"direction": "forward", "frame_id": ids[3], "frame_index": None}
    ]
    assert "stopped forward at frame" in job["message"]
    assert np.isfinite(_propagated(session_factory)[ids[1]][0].scores["sam2_iou"])


def test_a_runs_embeddings_are_precomputed_so_the_first_click_is_quick(
    client: TestClient, make_user, session_factory, tmp_path
) -> None:
    _, token = make_user("embedder", Role.reviewer)
    sequence_id, ids, _ = _run(client, token, 3)
    started = client.post(f"/api/v1/sequences/{sequence_id}/embeddings", headers=auth(token))
    assert started.status_code == 202, started.text
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded" and job["result"]["computed"] == 3
    again = client.post(f"/api/v1/sequences/{sequence_id}/embeddings", headers=auth(token))
    assert wait_for_job(client, again.json()["job_id"], token)["result"]["computed"] == 0
    click = client.post(
        f"/api/v1/frames/{ids[1]}/segment",
        json={"points": [{"x": 48, "y": 32, "positive": True}]},
        headers=auth(token),
    )
    assert click.status_code == 200 and click.json()["embedding"] in ("memory", "disk")
    assert (
        client.post("/api/v1/sequences/999999/embeddings", headers=auth(token)).status_code == 404
    )

    # A video import queues the same job for its run when SAM2's weights are here.
    path = tmp_path / "run.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (96, 64))
    for i in range(4):
        writer.write(synth_frame(seed=500 + i, params=SIZE).image[:, :, None].repeat(3, 2))
    writer.release()
    upload = client.post(
        "/api/v1/videos",
        files={"file": ("run.avi", path.read_bytes(), "video/x-msvideo")},
        data={"every_nth": "1"},
        headers=auth(token),
    )
    assert upload.status_code == 202, upload.text
    assert wait_for_job(client, upload.json()["job_id"], token)["status"] == "succeeded"
    with session_factory() as session:
        embed = session.scalars(
            sa.select(Job).where(Job.kind == "embed").order_by(Job.id.desc())
        ).first()
        assert embed is not None and embed.params == {
            "sequence_id": upload.json()["video"]["sequence_id"]
        }
    assert wait_for_job(client, embed.id, token)["result"]["computed"] == 4


def test_only_reviewers_propagate(client: TestClient, make_user) -> None:
    """Propagation writes proposals over a whole run: a reviewer's decision, as accepting is."""
    _, reviewer = make_user("rev", Role.reviewer)
    _, annotator = make_user("ann", Role.annotator)
    sequence_id, ids, frames = _run(client, reviewer, count=2)
    client.put(
        f"/api/v1/frames/{ids[0]}/label",
        json=corrected_label(frames[0].mask),
        headers=auth(reviewer),
    )
    refused = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[0]]},
        headers=auth(annotator),
    )
    assert refused.status_code == 403
