"""A weld run's timeline: geometry per frame from its label or the proposal shown, in pixels
and millimetres, JSON and CSV."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Proposal, Role
from app.proposals.files import store_mask
from app.storage import LocalStorage
from tests.helpers import auth, corrected_label, image_bytes


def _rect(x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    mask = np.zeros((100, 160), bool)
    mask[y0:y1, x0:x1] = True
    return mask


def test_a_runs_geometry_comes_from_labels_else_the_proposal_shown(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("timeline", Role.reviewer)
    sequence = client.post("/api/v1/sequences", json={"name": "Run"}, headers=auth(token)).json()
    patched = client.patch(
        f"/api/v1/sequences/{sequence['id']}", json={"mm_per_px": 0.1}, headers=auth(token)
    )
    assert patched.status_code == 200
    files = [
        ("files", (f"t{i}.png", image_bytes(160, 100, seed=40 + i), "image/png")) for i in range(4)
    ]
    stored = client.post(
        "/api/v1/frames", files=files, data={"sequence_id": sequence["id"]}, headers=auth(token)
    ).json()["stored"]
    labelled, proposed, rejected, untouched = (f["id"] for f in stored)
    # A label: 60 px long along x, 10 px across; a proposal: 40 × 20, SAM2 IoU 0.8.
    client.put(
        f"/api/v1/frames/{labelled}/label",
        json=corrected_label(_rect(20, 80, 40, 50)) | {"keypoints": [[20, 45], [79, 45]]},
        headers=auth(token),
    )
    with session_factory() as session:
        session.add(
            Proposal(
                frame_id=proposed,
                source="teacher",
                model_id="t",
                mask_path=store_mask(LocalStorage(settings.home), _rect(50, 90, 30, 50)),
                keypoints=[[50, 40]],
                scores={"sam2_iou": 0.8},
            )
        )
        session.commit()
    client.put(
        f"/api/v1/frames/{rejected}/label",
        json={"status": "rejected", "base_revision": 0},
        headers=auth(token),
    )

    response = client.get(f"/api/v1/sequences/{sequence['id']}/geometry", headers=auth(token))
    assert response.status_code == 200, response.text
    timeline = response.json()
    assert timeline["travel_deg"] == pytest.approx(0.0, abs=0.01)  # both masks lie along x
    rows = {row["frame_id"]: row for row in timeline["frames"]}
    assert [row["frame_id"] for row in timeline["frames"]] == [
        labelled,
        proposed,
        rejected,
        untouched,
    ]
    label_row = rows[labelled]
    assert (label_row["source"], label_row["confidence"]) == ("label", None)
    assert (label_row["area_px"], label_row["length_px"], label_row["width_px"]) == (600, 60, 10)
    assert label_row["centroid"] == pytest.approx([49.5, 44.5])
    assert label_row["keypoints"] == [[20, 45], [79, 45]]
    assert (label_row["length_mm"], label_row["width_mm"]) == pytest.approx((6.0, 1.0))
    assert label_row["area_mm2"] == pytest.approx(6.0)
    proposal_row = rows[proposed]
    assert (proposal_row["source"], proposal_row["confidence"]) == ("teacher", 0.8)
    assert (proposal_row["length_px"], proposal_row["width_px"]) == (40, 20)
    assert rows[rejected]["source"] == "label" and rows[rejected]["area_px"] is None
    assert rows[untouched]["source"] is None and rows[untouched]["status"] == "new"

    text = client.get(
        f"/api/v1/sequences/{sequence['id']}/geometry",
        params={"format": "csv"},
        headers=auth(token),
    )
    assert text.headers["content-type"].startswith("text/csv")
    table = list(csv.DictReader(io.StringIO(text.text)))
    assert [int(r["frame_id"]) for r in table] == [labelled, proposed, rejected, untouched]
    assert (table[0]["length_px"], table[0]["width_mm"], table[0]["k2_x"]) == ("60", "1", "79")
    assert table[1]["k2_x"] == "" and table[3]["area_px"] == ""

    missing = client.get("/api/v1/sequences/999999/geometry", headers=auth(token))
    assert missing.status_code == 404


def test_the_runs_travel_axis_is_the_median_of_undirected_axes() -> None:
    """Axes are undirected: 178° and 2° are 4° apart, so the median of 178, 2 and 1 is near 1°,
    not 2° (or 60°, their plain mean)."""
    from app.timeline.service import _median_axis

    assert _median_axis([178.0, 2.0, 1.0]) == pytest.approx(1.0, abs=0.01)
    assert _median_axis([10.0, 12.0, 80.0]) == pytest.approx(12.0, abs=0.01)
    assert _median_axis([]) is None


def test_a_runs_scale_set_from_two_points_a_known_distance_apart(
    client: TestClient, make_user
) -> None:
    """`PATCH /sequences/{id}` with ``scale_points``: two points 250 px apart that are 5 mm
    apart give 0.02 mm/px; points on one spot, a scale over the bound, or both ways at once
    are refused with a sentence and leave the scale as it was."""
    _, token = make_user("scaler", Role.annotator)
    run = client.post(
        "/api/v1/sequences", json={"name": "Scaled", "mm_per_px": 0.5}, headers=auth(token)
    ).json()
    url = f"/api/v1/sequences/{run['id']}"
    body = {"scale_points": {"points": [[100, 100], [250, 300]], "distance_mm": 5}}
    patched = client.patch(url, json=body, headers=auth(token))
    assert patched.status_code == 200, patched.text
    assert patched.json()["mm_per_px"] == pytest.approx(5 / 250)
    for wrong, status, words in (
        ({"points": [[10, 10], [10.5, 10]], "distance_mm": 5}, 422, "0.5 px apart"),
        ({"points": [[0, 0], [3, 4]], "distance_mm": 9000}, 422, "more than 100 mm per pixel"),
        ({"points": [[0, 0]], "distance_mm": 5}, 422, "at least 2 items"),
        ({"points": [[0, 0], [30, 40]], "distance_mm": 0}, 422, "greater than 0"),
    ):
        refused = client.patch(url, json={"scale_points": wrong}, headers=auth(token))
        assert refused.status_code == status, refused.text
        assert words in refused.text
    both = client.patch(url, json={**body, "mm_per_px": 0.1}, headers=auth(token))
    assert both.status_code == 422 and "not both" in both.text
    after = client.get(url, headers=auth(token)).json()
    assert after["mm_per_px"] == pytest.approx(0.02)
