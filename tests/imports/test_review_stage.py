"""An import's labels go through the review stage as a save through the API does: with
``WELDPOOL_REVIEW_STAGE`` on, an annotator's imported label awaits a reviewer and does not
train, an overwrite of an approved label awaits again, and a reviewer's import is approved."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Label, ReviewState, Role
from app.training.service import training_frame_ids
from tests.helpers import auth, image_bytes, run_cli
from tests.imports.common import H, W, label_mask, start_import, stored_labels, zipped
from weldpool_core.io import encode_mask_png


def _masks_zip(top: int) -> bytes:
    files = {}
    for i in range(2):
        mask = np.zeros((H, W), bool)
        mask[top : top + 20, 10 + 30 * i : 35 + 30 * i] = True
        files[f"images/f{i}.png"] = image_bytes(W, H, seed=900 + i)
        files[f"masks/f{i}.png"] = encode_mask_png(mask)
    return zipped(files)


def _labels(client: TestClient, token: str) -> dict[str, dict]:
    return {f["original_name"]: label for f, label in stored_labels(client, token) if label}


def _awaiting(client: TestClient, token: str) -> set[int]:
    listed = client.get("/api/v1/frames", params={"review": "awaiting"}, headers=auth(token))
    return {f["id"] for f in listed.json()["items"]}


def test_an_annotators_import_awaits_review_and_an_overwrite_of_an_approved_label_waits_again(
    client: TestClient, make_user, session_factory
) -> None:
    client.app.state.settings.review_stage = True  # type: ignore[attr-defined]
    _, reviewer = make_user("rita", Role.reviewer)
    _, annotator = make_user("anna", Role.annotator)
    start_import(client, annotator, _masks_zip(5), "masks")
    labels = _labels(client, annotator)
    assert {n: label["review"] for n, label in labels.items()} == {
        "f0.png": "awaiting",
        "f1.png": "awaiting",
    }
    ids = {n: label["frame_id"] for n, label in labels.items()}
    assert _awaiting(client, reviewer) == set(ids.values())
    with session_factory() as session:
        assert training_frame_ids(session) == []  # nothing trains before a reviewer approves
    approved = client.post(
        f"/api/v1/frames/{ids['f0.png']}/label/review",
        json={"decision": "approve", "base_revision": 1},
        headers=auth(reviewer),
    )
    assert approved.status_code == 200 and approved.json()["review"] == "approved"
    with session_factory() as session:
        assert training_frame_ids(session) == [ids["f0.png"]]

    start_import(client, annotator, _masks_zip(30), "masks", overwrite=True)
    after = _labels(client, annotator)
    assert after["f0.png"]["review"] == "awaiting"  # the annotator's new mask waits again
    assert label_mask(after["f0.png"])[35].any() and not label_mask(after["f0.png"])[6].any()
    assert _awaiting(client, reviewer) == set(ids.values())
    with session_factory() as session:
        assert training_frame_ids(session) == []

    start_import(client, reviewer, _masks_zip(5), "masks", overwrite=True)
    assert {label["review"] for label in _labels(client, reviewer).values()} == {"approved"}


def test_the_cli_imports_an_annotators_labels_to_await_review(
    settings, session_factory, make_user, tmp_path: Path
) -> None:
    make_user("anna", Role.annotator)
    folder = tmp_path / "set"
    for name, data in zipped_files(_masks_zip(5)).items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    env = {
        "WELDPOOL_HOME": str(settings.home),
        "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
        "WELDPOOL_REVIEW_STAGE": "true",
    }
    done = run_cli("import-labels", folder, "--format", "masks", "--user", "anna", env=env)
    assert done.returncode == 0, done.stderr
    with session_factory() as session:
        states = session.scalars(sa.select(Label.review)).all()
    assert states == [ReviewState.awaiting, ReviewState.awaiting]


def zipped_files(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        return {name: archive.read(name) for name in archive.namelist()}
