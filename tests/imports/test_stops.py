"""An import stops when it should, with one sentence: a cancel lands while a label is being
computed (not only between batches), a user deactivated mid-import stops it, and a bare image
name that two folders of the import hold is refused as ambiguous (not matched to a stored frame
of that name)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
import sqlalchemy as sa

from app.core.errors import PermissionDeniedError
from app.core.models import Label, Role, User
from app.imports.schemas import ImportOptions
from app.imports.service import import_labels
from app.storage import open_storage
from tests.helpers import auth, image_bytes, wait_for, wait_for_job
from tests.imports.common import H, W, masks_archive, stored_labels, zipped
from weldpool_core.annotations import open_source
from weldpool_core.annotations import shapes as shapes_module


def test_a_cancel_lands_while_a_label_is_being_computed(client, make_user, monkeypatch) -> None:
    _, token = make_user("canceller", Role.annotator)
    entered, release = threading.Event(), threading.Event()
    decode = shapes_module.MaskImage.mask

    def slow(self, height, width):  # type: ignore[no-untyped-def]
        entered.set()
        release.wait(60)  # a label whose work takes long
        return decode(self, height, width)

    monkeypatch.setattr(shapes_module.MaskImage, "mask", slow)
    try:
        response = client.post(
            "/api/v1/labels/import",
            data={"format": "masks"},
            files={"file": ("labels.zip", masks_archive(2, seed=500), "application/zip")},
            headers=auth(token),
        )
        job_id = response.json()["job_id"]
        assert entered.wait(30)
        cancelled = client.post(f"/api/v1/jobs/{job_id}/cancel", headers=auth(token))
        assert cancelled.status_code == 200, cancelled.text

        def ended() -> dict | None:
            job = client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()
            return job if job["status"] not in ("queued", "running") else None

        assert wait_for(ended, timeout=20)["status"] == "cancelled"
    finally:
        release.set()
    assert all(label is None for _, label in stored_labels(client, token))


def test_an_import_stops_when_its_user_is_deactivated(
    settings, session_factory, make_user, tmp_path: Path
) -> None:
    user, _ = make_user("leaver", Role.annotator)
    archive = tmp_path / "labels.zip"
    archive.write_bytes(masks_archive(70, seed=500))  # two batches

    def deactivate(fraction: float, message: str) -> None:
        with session_factory() as other:
            other.execute(sa.update(User).where(User.id == user.id).values(is_active=False))
            other.commit()

    source = open_source(archive)
    with session_factory() as session, pytest.raises(PermissionDeniedError) as stopped:
        import_labels(
            session,
            open_storage(settings),
            source,
            ImportOptions("masks"),
            session.get_one(User, user.id),
            deactivate,
        )
    source.close()
    assert "leaver was deactivated during the import" in stopped.value.message
    with session_factory() as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(Label)) == 64


def test_a_bare_image_name_two_folders_hold_is_refused_as_ambiguous(client, make_user) -> None:
    _, token = make_user("lab", Role.reviewer)
    run = client.post("/api/v1/sequences", json={"name": "here"}, headers=auth(token)).json()
    stored = client.post(
        "/api/v1/frames",
        data={"sequence_id": run["id"]},
        files=[("files", ("x.png", image_bytes(W, H, seed=1), "image/png"))],
        headers=auth(token),
    )
    assert stored.status_code == 201, stored.text
    document = {
        "images": [{"id": 1, "file_name": "x.png", "width": W, "height": H}],
        "categories": [{"id": 1, "name": "pool"}],
        "annotations": [
            {"id": 1, "image_id": 1, "category_id": 1, "segmentation": [[5, 5, 40, 5, 40, 30]]}
        ],
    }
    archive = zipped(
        {
            "annotations.json": json.dumps(document).encode(),
            "a/x.png": image_bytes(W, H, seed=2),
            "b/x.png": image_bytes(W, H, seed=3),
        }
    )
    response = client.post(
        "/api/v1/labels/import",
        data={"format": "coco"},
        files={"file": ("labels.zip", archive, "application/zip")},
        headers=auth(token),
    )
    job = wait_for_job(client, response.json()["job_id"], token, timeout=60)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["labels"] == 0
    [refusal] = job["result"]["refused"]
    assert "'x.png' is ambiguous" in refusal["reason"] and "a/x.png, b/x.png" in refusal["reason"]
    assert all(label is None for _, label in stored_labels(client, token))
