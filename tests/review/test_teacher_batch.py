"""A GPU worker's teacher run puts a chunk's frames through DINO and SAM2's encoder at once
(``WELDPOOL_TEACHER_BATCH``; tested on the CPU by setting it): the same proposals as one frame
at a time, and a frame whose file is lost still fails alone, with its sentence."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Frame, Proposal, Role
from app.main import create_app
from app.storage import LocalStorage
from app.storage.pixels import load_mask
from tests.helpers import auth, image_bytes, wait_for_job
from weldpool_core.teacher.teacher import Teacher


def _masks(settings, session_factory) -> dict[str, np.ndarray]:
    storage = LocalStorage(settings.home)
    with session_factory() as session:
        return {
            session.get_one(Frame, p.frame_id).sha256: load_mask(storage, p.mask_path)
            for p in session.query(Proposal).all()
        }


def test_a_batched_run_proposes_what_one_frame_at_a_time_does(
    settings, session_factory, make_user, monkeypatch, tmp_path
) -> None:
    _, token = make_user("gpu", Role.reviewer)
    files = [
        ("files", (f"b{i}.png", image_bytes(64, 48, seed=120 + i), "image/png")) for i in range(4)
    ]
    calls: list[int] = []
    real = Teacher.run_many

    def counted(self, images, *args, **kwargs):  # type: ignore[no-untyped-def]
        calls.append(len(images))
        return real(self, images, *args, **kwargs)

    monkeypatch.setattr(Teacher, "run_many", counted)
    results = {}
    for batch in (1, 4):
        home = tmp_path / f"batch-{batch}"
        run_settings = settings.model_copy(update={"teacher_batch": batch, "home": home})
        with TestClient(create_app(run_settings, embedded_worker=True)) as client:
            stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()
            ids = [f["id"] for f in stored["stored"]]
            lost = session_factory().get_one(Frame, ids[1]).path
            (home / lost).unlink()  # one frame's image is lost
            started = client.post(
                "/api/v1/teacher/runs", json={"frame_ids": ids}, headers=auth(token)
            )
            job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
        assert job["status"] == "succeeded", job["error"]
        assert job["result"]["proposed"] == 3
        assert [f["frame_id"] for f in job["result"]["failed"]] == [ids[1]]
        results[batch] = _masks(run_settings, session_factory)
        with session_factory() as session:  # the next round starts from an empty database
            for table in (Proposal, Frame):
                session.query(table).delete()
            session.commit()
    assert calls == [3]  # the batched run: the three readable frames at once; the other, none
    assert results[1].keys() == results[4].keys() and len(results[1]) == 3
    for sha, mask in results[1].items():
        assert (mask != results[4][sha]).mean() < 1e-3
