"""The first click on a frame: its embedding made when the review page opens (bounded), and a
previous mask the server already has named instead of sent."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.teacher import warm
from tests.factories import form_login, run_teacher, upload_synthetic
from tests.helpers import auth, corrected_label, mask_from_b64, wait_for


def test_an_embedding_asked_for_first_is_in_memory_for_the_first_click(
    client: TestClient,
    people,
) -> None:
    token = people["annotator"]
    frame_id = upload_synthetic(client, token, 1)[0]
    before = client.get(f"/api/v1/frames/{frame_id}/embedding", headers=auth(token)).json()
    assert before["state"] == "cold"  # a look starts nothing
    asked = client.post(f"/api/v1/frames/{frame_id}/embedding", headers=auth(token))
    assert asked.status_code == 200 and asked.json()["state"] in ("computing", "ready")

    def state() -> dict:
        return client.get(f"/api/v1/frames/{frame_id}/embedding", headers=auth(token)).json()

    ready = wait_for(lambda: (found := state())["state"] == "ready" and found, timeout=60)
    assert ready["expected_ms"] > 0  # measured on this computation
    click = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={"points": [{"x": 80, "y": 50, "positive": True}]},
        headers=auth(token),
    )
    assert (
        click.json()["embedding"] == "memory"
    )  # not "computed": the first click waits for nothing


def test_the_warming_budget_is_bounded(client: TestClient, people, monkeypatch) -> None:
    token = people["annotator"]
    frame_ids = upload_synthetic(client, token, 3)
    monkeypatch.setattr(warm, "MAX_PENDING", 1)
    gate = __import__("threading").Event()
    real = warm._compute
    monkeypatch.setattr(warm, "_compute", lambda *a: (gate.wait(30), real(*a)))
    try:
        states = [
            client.post(f"/api/v1/frames/{f}/embedding", headers=auth(token)).json()["state"]
            for f in frame_ids
        ]
        assert states == ["computing", "busy", "busy"]
    finally:
        gate.set()


def test_a_click_names_the_mask_the_server_has_instead_of_sending_it(
    client: TestClient,
    people,
) -> None:
    token = people["reviewer"]
    frame_ids = upload_synthetic(client, token, 2)
    run_teacher(client, token, frame_ids)
    frame_id = frame_ids[0]
    proposal = client.get(f"/api/v1/frames/{frame_id}/proposal", headers=auth(token)).json()
    mask = np.zeros((100, 160), bool)
    mask[30:70, 40:120] = True
    saved = client.put(
        f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
    )
    assert saved.status_code == 200
    points = [{"x": 60, "y": 50, "positive": True}]

    def click(**extra: object) -> dict:
        answer = client.post(
            f"/api/v1/frames/{frame_id}/segment",
            json={"points": points, **extra},
            headers=auth(token),
        )
        assert answer.status_code == 200, answer.text
        return answer.json()

    sent = click(mask_png=saved.json()["mask_png"])
    named = click(mask_from={"label_revision": 1})
    assert np.array_equal(mask_from_b64(named["mask_png"]), mask_from_b64(sent["mask_png"]))
    by_proposal = click(mask_from={"proposal_id": proposal["id"]})
    assert np.array_equal(
        mask_from_b64(by_proposal["mask_png"]),
        mask_from_b64(click(mask_png=proposal["mask_png"])["mask_png"]),
    )

    stale = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={"points": points, "mask_from": {"label_revision": 7}},
        headers=auth(token),
    )
    assert stale.status_code == 409 and stale.json() == {
        "detail": "The label is at revision 1, not 7; reload the frame and refine the mask it "
        "shows.",  # not the save's advice to overwrite with a base_revision
        "revision": 1,
    }
    other = client.get(f"/api/v1/frames/{frame_ids[1]}/proposal", headers=auth(token)).json()
    foreign = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={"points": points, "mask_from": {"proposal_id": other["id"]}},
        headers=auth(token),
    )
    assert foreign.status_code == 404
    for bad in (
        {"mask_png": sent["mask_png"], "mask_from": {"label_revision": 1}},
        {"mask_from": {}},
        {"mask_from": {"label_revision": 1, "proposal_id": 1}},
    ):
        refused = client.post(
            f"/api/v1/frames/{frame_id}/segment",
            json={"points": points, **bad},
            headers=auth(token),
        )
        assert refused.status_code in (400, 422), bad


@pytest.fixture(autouse=True)
def _no_leftover_warming() -> None:
    warm._pending.clear()


def test_the_embedding_cache_is_sized_listed_and_cleared_by_admins(
    client: TestClient,
    people,
    make_user,
) -> None:
    from app.core.models import Role

    _, admin = make_user("ada", Role.admin)
    token = people["annotator"]
    frame_id = upload_synthetic(client, token, 1)[0]
    click = {"points": [{"x": 80, "y": 50, "positive": True}]}
    segment = f"/api/v1/frames/{frame_id}/segment"
    assert client.post(segment, json=click, headers=auth(token)).json()["embedding"] == "computed"
    cache = client.get("/api/v1/system/embedding-cache", headers=auth(token)).json()
    assert cache["files"] == 1 and cache["bytes"] > 0
    assert cache["limit_bytes"] == int(client.app.state.settings.embedding_cache_mb * 2**20)  # type: ignore[attr-defined]
    refused = client.delete("/api/v1/system/embedding-cache", headers=auth(token))
    assert refused.status_code == 403
    cleared = client.delete("/api/v1/system/embedding-cache", headers=auth(admin)).json()
    assert cleared == {"removed_files": 1, "removed_bytes": cache["bytes"]}
    assert client.get("/api/v1/system/embedding-cache", headers=auth(token)).json()["files"] == 0
    assert client.post(segment, json=click, headers=auth(token)).json()["embedding"] == "computed"


def test_the_jobs_page_filters_by_every_job_kind(client: TestClient, make_user) -> None:
    from app.jobs.registry import job_kinds

    make_user("kai", password="kai-password")
    assert form_login(client, "kai", "kai-password").status_code == 303
    page = client.get("/jobs").text
    kinds = job_kinds()
    assert {"teacher", "train_student", "import_labels", "export", "propagate", "embed"} <= set(
        kinds
    )
    for kind in kinds:
        assert f"<option>{kind}</option>" in page
