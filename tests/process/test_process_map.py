"""The process map over the demo's plant runs: the fit, an outlier, the oscillating run's
signature, staleness, CSV and bad names (app.process)."""

from __future__ import annotations

import csv
import io
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from app.demo import OSCILLATING, PROCESS_RUNS, fill_process_runs
from tests.helpers import auth, corrected_label


@pytest.fixture
def runs(client: TestClient, settings: Any, session_factory: Any, make_user: Any) -> dict:
    """The demo's six plant runs (30 frames each, 2 s at 15 fps) and a reviewer's token."""
    with session_factory() as session:
        fill_process_runs(session, settings, frames=30, progress=lambda _t: None)
    _, token = make_user("engineer", Role.reviewer)
    listed = client.get("/api/v1/sequences", headers=auth(token)).json()
    ids = sorted(s["id"] for s in listed)
    return {"token": token, "ids": ids}


def _map(client: TestClient, token: str, **params: str) -> dict:
    response = client.get("/api/v1/process-map", params=params, headers=auth(token))
    assert response.status_code == 200, response.text
    return response.json()


def test_width_follows_the_plants_law_and_a_run_off_it_is_flagged(
    client: TestClient, runs: dict
) -> None:
    token = runs["token"]
    found = _map(client, token, x="heat_input_j_mm", y="width_mm")
    points = found["points"]
    assert [p["sequence_id"] for p in points] == runs["ids"]
    heat = [v * a / (s / 6) for v, a, s in PROCESS_RUNS]
    assert [p["x"] for p in points] == pytest.approx(heat)
    assert found["fit"]["kind"] == "power"
    assert found["fit"]["b"] == pytest.approx(0.5, abs=0.05)  # Rosenthal: w ∝ √(heat input)
    assert found["fit"]["b_low"] < found["fit"]["b"] < found["fit"]["b_high"]
    assert found["fit"]["r2"] > 0.95
    assert not any(p["outlier"] for p in points)
    assert all(p["y_q1"] <= p["y"] <= p["y_q3"] for p in points)
    # a run measured 15 % wider (its scale changed): flagged, and the law stays
    moved = runs["ids"][1]
    scale = client.get(f"/api/v1/sequences/{moved}", headers=auth(token)).json()["mm_per_px"]
    patched = client.patch(
        f"/api/v1/sequences/{moved}", json={"mm_per_px": scale * 1.15}, headers=auth(token)
    )
    assert patched.status_code == 200, patched.text
    found = _map(client, token, x="heat_input_j_mm", y="width_mm")
    assert [p["sequence_id"] for p in found["points"] if p["outlier"]] == [moved]
    assert found["fit"]["b"] == pytest.approx(0.5, abs=0.05)
    assert found["fit"]["excluded"] == [1]


def test_the_oscillating_run_has_its_frequency_and_an_unstable_stretch(
    client: TestClient, runs: dict
) -> None:
    token = runs["token"]
    wobbly = runs["ids"][OSCILLATING]
    signature = client.get(f"/api/v1/sequences/{wobbly}/signature", headers=auth(token)).json()
    assert signature["unit"] == "mm"
    assert signature["oscillation"]["hz"] == pytest.approx(3.0, abs=0.2)
    (stretch,) = signature["stretches"]
    assert 7 <= stretch["start_frame_index"] <= 12 and 17 <= stretch["end_frame_index"] <= 22
    steady = client.get(f"/api/v1/sequences/{runs['ids'][0]}/signature", headers=auth(token))
    assert steady.json()["stretches"] == []
    found = _map(client, token, x="current_a", y="width_cv", color="oscillation_hz")
    cvs = {p["sequence_id"]: p["y"] for p in found["points"]}
    assert max(cvs, key=cvs.__getitem__) == wobbly
    first = {p["sequence_id"]: p["first_unstable_frame_id"] for p in found["points"]}
    assert first[wobbly] == stretch["frame_ids"][0]
    # the frames list filters on unstable frames; the queue can keep to them
    listed = client.get(
        "/api/v1/frames", params={"unstable": "true", "limit": 500}, headers=auth(token)
    ).json()
    assert sorted(f["id"] for f in listed["items"]) == sorted(stretch["frame_ids"])


def test_a_changed_label_makes_the_signature_stale_and_it_is_measured_again(
    client: TestClient, runs: dict, session_factory: Any
) -> None:
    import numpy as np

    from app.core.models import RunSignature

    token = runs["token"]
    run = runs["ids"][0]
    before = client.get(f"/api/v1/sequences/{run}/signature", headers=auth(token)).json()
    frames = client.get(
        "/api/v1/frames", params={"sequence_id": run, "limit": 500}, headers=auth(token)
    ).json()["items"]
    for frame in frames[:20]:  # most of the run: a narrow pool, 16 px across
        mask = np.zeros((frame["height"], frame["width"]), bool)
        mask[92:108, 40:200] = True
        state = client.get(f"/api/v1/frames/{frame['id']}", headers=auth(token)).json()
        revision = state["label"]["revision"] if state.get("label") else 1
        saved = client.put(
            f"/api/v1/frames/{frame['id']}/label",
            json=corrected_label(mask, base_revision=revision),
            headers=auth(token),
        )
        assert saved.status_code == 200, saved.text
    with session_factory() as session:
        stored = session.query(RunSignature).filter_by(sequence_id=run).one()
        assert stored.stale
    after = client.get(f"/api/v1/sequences/{run}/signature", headers=auth(token)).json()
    assert after["width"]["median"] < before["width"]["median"] / 2


def test_csv_and_bad_names(client: TestClient, runs: dict) -> None:
    token = runs["token"]
    response = client.get(
        "/api/v1/process-map",
        params={"x": "robot_speed_cm_min", "y": "length_mm", "format": "csv"},
        headers=auth(token),
    )
    assert response.status_code == 200 and response.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(response.text)))
    assert len(rows) == len(PROCESS_RUNS)
    assert float(rows[0]["robot_speed_cm_min"]) == PROCESS_RUNS[0][2]
    assert float(rows[0]["length_mm"]) > 0
    bad = client.get("/api/v1/process-map", params={"x": "bogus"}, headers=auth(token))
    assert bad.status_code == 422 and "detail" in bad.json()
