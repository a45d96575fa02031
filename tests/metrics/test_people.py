"""Per-person figures (`GET /metrics/people`) against values computed by hand on a fixed
history: an annotator's four submissions (one sent back, one corrected by the reviewer), the
reviewer's four decisions, at known times."""

from __future__ import annotations

import csv
import datetime as dt
import io

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import LabelRevision, Role
from tests.factories import frame_ids, random_images
from tests.helpers import auth, mask_b64

T0 = dt.datetime(2026, 1, 5, 9, 0, tzinfo=dt.UTC)
WIDE = [[10.0, 10.0], [39.0, 29.0]]  # the keypoints saved with the wide mask
NARROW = [[10.0, 10.0], [24.0, 29.0]]  # … and with the narrow one


def _mask(right: int) -> np.ndarray:
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:right] = True
    return mask


WIDE_MASK, NARROW_MASK = _mask(40), _mask(25)  # 600 px and 300 px inside it: IoU 0.5


def _save(client: TestClient, token: str, frame: int, base: int, wide: bool) -> None:
    body = {
        "status": "corrected",
        "base_revision": base,
        "mask_png": mask_b64(WIDE_MASK if wide else NARROW_MASK),
        "keypoints": WIDE if wide else NARROW,
    }
    answer = client.put(f"/api/v1/frames/{frame}/label", json=body, headers=auth(token))
    assert answer.status_code == 200, answer.text


def _decide(client: TestClient, token: str, frame: int, base: int, comment: str = "") -> None:
    body = {"decision": "return" if comment else "approve", "base_revision": base}
    answer = client.post(
        f"/api/v1/frames/{frame}/label/review",
        json=body | {"comment": comment},
        headers=auth(token),
    )
    assert answer.status_code == 200, answer.text


@pytest.fixture
def history(client: TestClient, make_user, session_factory) -> dict[str, str]:
    """anna submits f1 (narrow, 09:00), f2 (wide, 09:02), f3 (wide, 09:03); rita sends f1 back
    (09:10), approves f2 (09:11), corrects f3 to narrow and approves it (09:12); anna submits f1
    again (wide, 09:30), rita approves it (09:40)."""
    client.app.state.settings.review_stage = True  # type: ignore[attr-defined]
    _, rita = make_user("rita", Role.reviewer)
    _, anna = make_user("anna")
    make_user("otto")  # no work at all: a row of zeros and blanks
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(rita)).json()
    f1, f2, f3 = frame_ids(
        client, rita, random_images([("1", 1), ("2", 2), ("3", 3)]), sequence_id=run["id"]
    )
    _save(client, anna, f1, 0, wide=False)
    _save(client, anna, f2, 0, wide=True)
    _save(client, anna, f3, 0, wide=True)
    _decide(client, rita, f1, 1, comment="The pool goes on to the right.")
    _decide(client, rita, f2, 1)
    _save(client, rita, f3, 1, wide=False)  # corrects and approves in one step
    _save(client, anna, f1, 2, wide=True)
    _decide(client, rita, f1, 3)
    minutes = {(f1, 1): 0, (f2, 1): 2, (f3, 1): 3, (f1, 2): 10, (f2, 2): 11, (f3, 2): 12}
    minutes |= {(f1, 3): 30, (f1, 4): 40}
    with session_factory() as session:
        for (frame, revision), minute in minutes.items():
            session.execute(
                sa.update(LabelRevision)
                .where(LabelRevision.frame_id == frame, LabelRevision.revision == revision)
                .values(created_at=T0 + dt.timedelta(minutes=minute))
            )
        session.commit()
    return {"rita": rita, "anna": anna}


def _rows(client: TestClient, token: str, **params: str) -> dict[str, dict]:
    answer = client.get("/api/v1/metrics/people", params=params, headers=auth(token))
    assert answer.status_code == 200, answer.text
    return {row["username"]: row for row in answer.json()["people"]}


def test_figures_per_person_match_the_hand_computed_ones(client: TestClient, history) -> None:
    rows = _rows(client, history["rita"])
    assert list(rows) == ["anna", "otto", "rita"]
    anna, rita = rows["anna"], rows["rita"]
    assert (anna["labels_saved"], anna["submitted"], anna["sent_back"]) == (4, 4, 1)
    assert anna["sent_back_rate"] == 0.25
    # 09:00 → 09:02 → 09:03 count (120 s + 60 s for two frames); 09:03 → 09:30 is a pause.
    assert anna["seconds_per_frame"] == pytest.approx(90.0)
    assert anna["frames_per_hour"] == pytest.approx(40.0)
    assert anna["active_hours"] == pytest.approx(180 / 3600)
    # Against what was approved: f1 narrow vs wide 0.5, f2 1, f3 wide vs narrow 0.5, f1 again 1;
    # keypoints: one of two points 15 px off on f1 (first) and f3, none on the others.
    assert anna["compared_with_approved"] == 4
    assert anna["iou_vs_approved"] == pytest.approx(0.75)
    assert anna["keypoint_px_vs_approved"] == pytest.approx(3.75)
    assert anna["decisions"] == 0 and anna["turnaround_median_s"] is None

    assert (rita["labels_saved"], rita["submitted"], rita["sent_back_rate"]) == (1, 0, None)
    assert rita["seconds_per_frame"] == pytest.approx(60.0)  # 09:11 → her save at 09:12
    assert (rita["decisions"], rita["approved"]) == (4, 2)
    assert (rita["corrected_and_approved"], rita["returned"]) == (1, 1)
    assert rita["turnaround_median_s"] == pytest.approx(570.0)  # of 600, 540, 540, 600
    otto = rows["otto"]
    assert otto["labels_saved"] == 0 and otto["frames_per_hour"] is None


def test_a_period_counts_what_happened_in_it(client: TestClient, history) -> None:
    rows = _rows(client, history["rita"], since="2026-01-05T09:20:00Z", until="2026-01-06")
    anna, rita = rows["anna"], rows["rita"]
    assert (anna["labels_saved"], anna["sent_back"], anna["sent_back_rate"]) == (1, 0, 0.0)
    assert anna["iou_vs_approved"] == 1.0 and anna["seconds_per_frame"] is None
    assert (rita["decisions"], rita["approved"], rita["turnaround_median_s"]) == (1, 1, 600.0)
    before = _rows(client, history["rita"], until="2026-01-05T09:00:00Z")
    assert before["anna"]["labels_saved"] == 0
    wrong = client.get(
        "/api/v1/metrics/people",
        params={"since": "2026-01-06", "until": "2026-01-05"},
        headers=auth(history["rita"]),
    )
    assert wrong.status_code == 400 and "until" in wrong.json()["detail"]


def test_an_annotator_sees_her_own_row_and_csv_holds_the_same(client: TestClient, history) -> None:
    assert list(_rows(client, history["anna"])) == ["anna"]
    answer = client.get(
        "/api/v1/metrics/people", params={"format": "csv"}, headers=auth(history["rita"])
    )
    assert answer.headers["content-type"].startswith("text/csv")
    table = {r["username"]: r for r in csv.DictReader(io.StringIO(answer.text))}
    assert table["anna"]["iou_vs_approved"] == "0.75"
    assert table["anna"]["sent_back_rate"] == "0.25"
    assert table["rita"]["turnaround_median_s"] == "570"
    assert table["otto"]["iou_vs_approved"] == ""
