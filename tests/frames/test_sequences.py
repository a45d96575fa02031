"""Weld runs: a scale is stored only within its physical range, and a stored row never breaks a
read (a value from before a check existed, or written by hand, is read as it is or as null)."""

from __future__ import annotations

import io
import json
import math
import zipfile

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Role, Sequence
from tests.helpers import auth, corrected_label, image_bytes


def test_a_scale_outside_the_physical_range_is_refused_and_not_stored(
    client: TestClient, make_user
) -> None:
    """Points 1e300 px apart and 1e-300 mm: the quotient underflows to 0 mm per pixel, which
    was stored and then failed every `GET /sequences`."""
    _, token = make_user("scaler", Role.annotator)
    run = client.post(
        "/api/v1/sequences", json={"name": "Tiny", "mm_per_px": 0.05}, headers=auth(token)
    ).json()
    url = f"/api/v1/sequences/{run['id']}"
    far = {"points": [[-5e299, 0], [5e299, 0]], "distance_mm": 1e-300}
    for body in ({"scale_points": far}, {"mm_per_px": 1e-300}, {"mm_per_px": 5e-7}):
        refused = client.patch(url, json=body, headers=auth(token))
        assert refused.status_code == 422, (body, refused.text)
        assert refused.json()["errors"]
        detail = refused.json()["detail"]
        assert detail.endswith(".") and detail.count(". ") == 0, detail  # one sentence
    assert (
        "under 1e-06 mm per pixel"
        in client.patch(url, json={"scale_points": far}, headers=auth(token)).json()["detail"]
    )
    listed = client.get("/api/v1/sequences", headers=auth(token))
    assert listed.status_code == 200
    assert [s["mm_per_px"] for s in listed.json() if s["id"] == run["id"]] == [0.05]
    least = 1e-6  # MIN_MM_PER_PX
    fine = client.patch(url, json={"mm_per_px": least}, headers=auth(token))
    assert fine.status_code == 200 and fine.json()["mm_per_px"] == least


@pytest.mark.parametrize("stored", [0.0, 1e9, -0.5, math.nan])
def test_a_bad_stored_row_still_lists_and_shows_its_geometry(
    client: TestClient, make_user, session_factory, stored: float
) -> None:
    """A row planted in the database past every check: the lists, the run, its timeline (JSON
    and CSV) answer 200; the scale reads as null and no millimetre is made up from it."""
    _, token = make_user("reader", Role.annotator)
    run = client.post("/api/v1/sequences", json={"name": "Planted"}, headers=auth(token)).json()
    files = [("files", ("p.png", image_bytes(160, 100, seed=7), "image/png"))]
    frame = client.post(
        "/api/v1/frames", files=files, data={"sequence_id": run["id"]}, headers=auth(token)
    ).json()["stored"][0]
    mask = np.zeros((100, 160), bool)
    mask[40:50, 20:80] = True
    labelled = client.put(
        f"/api/v1/frames/{frame['id']}/label", json=corrected_label(mask), headers=auth(token)
    )
    assert labelled.status_code == 200, labelled.text
    with session_factory() as session:
        session.execute(
            sa.update(Sequence)
            .where(Sequence.id == run["id"])
            .values(mm_per_px=stored, voltage_v=-3.0, wire_feed_m_min=stored, name="")
        )
        session.commit()

    listed = client.get("/api/v1/sequences", headers=auth(token))
    assert listed.status_code == 200, listed.text
    (row,) = [s for s in listed.json() if s["id"] == run["id"]]
    assert row["mm_per_px"] is None and row["voltage_v"] == -3.0 and row["name"] == ""
    one = client.get(f"/api/v1/sequences/{run['id']}", headers=auth(token))
    assert one.status_code == 200 and one.json()["mm_per_px"] is None
    geometry = client.get(f"/api/v1/sequences/{run['id']}/geometry", headers=auth(token))
    assert geometry.status_code == 200, geometry.text
    assert geometry.json()["mm_per_px"] is None
    (pool,) = geometry.json()["frames"]
    assert pool["area_px"] == 600 and pool["area_mm2"] is None and pool["length_mm"] is None
    csv = client.get(
        f"/api/v1/sequences/{run['id']}/geometry", params={"format": "csv"}, headers=auth(token)
    )
    assert csv.status_code == 200
    exported = client.get("/api/v1/export", params={"format": "coco"}, headers=auth(token))
    assert exported.status_code == 200, exported.text
    with zipfile.ZipFile(io.BytesIO(exported.content)) as archive:
        text = archive.read("annotations.json").decode()
    assert "NaN" not in text and "Infinity" not in text  # strict JSON for every reader
    (image,) = json.loads(text)["images"]
    assert image["process"]["mm_per_px"] is None
    # Editing the run still works, and a good scale replaces the bad one.
    fixed = client.patch(
        f"/api/v1/sequences/{run['id']}", json={"mm_per_px": 0.1}, headers=auth(token)
    )
    assert fixed.status_code == 200 and fixed.json()["mm_per_px"] == 0.1
