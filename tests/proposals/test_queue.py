"""The review queue (``app.proposals.queue``): each frame's score from its latest proposals,
the reason shown, the diverse head, and what list pages read."""

from __future__ import annotations

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Frame, Proposal, Role
from app.proposals.queue import rescore_frame
from app.review import propagation
from app.storage import open_storage
from tests.factories import frame_ids, numbered, random_images
from tests.helpers import auth


def _propose(
    session_factory, frame_id: int, sam2_iou: float, stability: float, descriptor: list[float]
) -> None:
    with session_factory() as session:
        frame = session.get_one(Frame, frame_id)
        session.add(
            Proposal(
                frame_id=frame_id,
                source="teacher",
                model_id="t",
                mask_path="artefacts/none.png",
                scores={"sam2_iou": sam2_iou, "prompt_stability": stability},
            )
        )
        frame.descriptor = descriptor
        session.flush()
        rescore_frame(session, frame, {"teacher_iou": 1.0, "instability": 1.0})
        session.commit()


def test_unstable_proposal_ranks_above_stable_and_reason_is_shown(
    client: TestClient, session_factory, make_user
) -> None:
    _, token = make_user("queue", Role.reviewer)
    stable, unstable, unscored = frame_ids(
        client, token, random_images(numbered(3, first_seed=200), width=32, height=24)
    )
    _propose(session_factory, stable, sam2_iou=0.9, stability=0.97, descriptor=[1.0, 0.0])
    _propose(session_factory, unstable, sam2_iou=0.9, stability=0.35, descriptor=[0.0, 1.0])
    queue = client.get(
        "/api/v1/frames", params={"order": "uncertainty"}, headers=auth(token)
    ).json()["items"]
    assert [f["id"] for f in queue] == [unstable, stable, unscored]
    assert queue[0]["uncertainty_reason"] == "instability"
    detail = client.get(f"/api/v1/frames/{unstable}", headers=auth(token)).json()
    assert detail["uncertainty_components"]["instability"] == 0.65


def test_diversity_breaks_runs_of_near_identical_frames(
    client: TestClient, session_factory, make_user
) -> None:
    _, token = make_user("diverse", Role.reviewer)
    ids = frame_ids(client, token, random_images(numbered(6, first_seed=200), width=32, height=24))
    for index, frame_id in enumerate(ids[:5]):  # five look-alikes; the last is the most unsure
        _propose(session_factory, frame_id, 0.5, 0.5 - 0.01 * index, [1.0, 0.01 * index])
    _propose(session_factory, ids[5], 0.6, 0.5, [0.0, 1.0])  # different, a bit less uncertain
    order = [
        f["id"]
        for f in client.get(
            "/api/v1/frames", params={"order": "uncertainty"}, headers=auth(token)
        ).json()["items"]
    ]
    assert order[0] == ids[4] and order[1] == ids[5]  # the most unsure, then the different one


def test_lists_never_read_descriptors_but_the_diversity_pick_does(
    client: TestClient, session_factory, make_user
) -> None:
    """A descriptor is 384 floats of JSON per frame: list pages leave it in the database; only
    the queue's diversity pick (which needs it) reads it, in the same query as its frames."""
    _, token = make_user("lists", Role.reviewer)
    ids = frame_ids(client, token, random_images(numbered(3, first_seed=200), width=32, height=24))
    for index, frame_id in enumerate(ids):
        _propose(session_factory, frame_id, 0.5, 0.5, [1.0, 0.1 * index])
    statements: list[str] = []

    def record(_conn, _cursor, statement, *_args) -> None:  # type: ignore[no-untyped-def]
        statements.append(statement)

    engine = client.app.state.engine
    sa.event.listen(engine, "before_cursor_execute", record)
    try:
        for order in ("id", "-id", "frame_index"):
            page = client.get("/api/v1/frames", params={"order": order}, headers=auth(token))
            assert len(page.json()["items"]) == 3
        assert not [s for s in statements if "descriptor" in s]
        queue = client.get("/api/v1/frames", params={"order": "uncertainty"}, headers=auth(token))
        assert len(queue.json()["items"]) == 3
        reads = [s for s in statements if "descriptor" in s]
        assert len(reads) == 1 and "LIMIT" in reads[0].upper()  # one query, not one per frame
    finally:
        sa.event.remove(engine, "before_cursor_execute", record)


def test_a_propagated_mask_sam2_doubts_ranks_above_a_confident_one(
    client: TestClient, session_factory, settings, make_user
) -> None:
    """Propagation's confidence is a component of the queue's score: two frames whose
    propagated masks came with confidence 0.2 and 0.9, recorded through propagation's own
    write; the doubted one comes first, for that reason, and the weight turns it off."""
    _, token = make_user("carrier", Role.reviewer)
    confident, doubted = frame_ids(
        client, token, random_images(numbered(2, first_seed=200), width=32, height=24)
    )
    storage = open_storage(settings)
    mask = np.zeros((24, 32), bool)
    mask[8:16, 10:22] = True
    weights = settings.uncertainty_weights
    with session_factory() as session:
        for frame_id, confidence in ((confident, 0.9), (doubted, 0.2)):
            scores = {"confidence": confidence, "from_frame_id": frame_id}
            frame = session.get_one(Frame, frame_id)
            propagation.record(session, storage, frame, mask, scores, "sam2-video:t", None, weights)
    queue = client.get(
        "/api/v1/frames", params={"order": "uncertainty"}, headers=auth(token)
    ).json()["items"]
    assert [f["id"] for f in queue] == [doubted, confident]
    assert queue[0]["uncertainty_reason"] == "propagation_doubt"
    assert queue[0]["uncertainty"] == pytest.approx(0.8)
    assert queue[1]["uncertainty"] == pytest.approx(0.1)
    with session_factory() as session:
        frame = session.get_one(Frame, doubted)
        rescore_frame(session, frame, weights | {"propagation_doubt": 0.0})
        assert frame.uncertainty is None  # no other component: unscored
