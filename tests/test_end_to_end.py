"""The whole loop, on SQLite and on PostgreSQL, with tiny random-weight teacher models:
upload → teacher job → proposal → click → labels → training job → model version with metrics →
promotion → student proposals → export that `weldpool train` reads back. And a worker killed
during training: the job fails, no version is half-written, the next training succeeds."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import cv2
import pytest
from fastapi.testclient import TestClient

from app.core.db import create_db_engine, create_session_factory
from app.core.models import Job, JobStatus, ModelVersion, Role, User
from app.core.schema import migrate
from app.core.security import issue_token
from app.jobs.queue import JobQueue
from app.jobs.service import create_job
from app.main import create_app
from tests.helpers import REPO, auth, corrected_label, make_settings, wait_for, wait_for_job
from tests.models import save_tiny_teacher
from weldpool_core.synth import SynthParams, synth_sequence

pytestmark = pytest.mark.slow
SIZE = SynthParams(width=192, height=120)


@pytest.fixture(scope="module")
def teacher_weights(tmp_path_factory) -> dict[str, object]:
    return save_tiny_teacher(tmp_path_factory.mktemp("weights"))


def test_the_whole_loop(tmp_path: Path, database_url: str, teacher_weights) -> None:
    settings = make_settings(
        tmp_path / "home", database_url=database_url, retrain_every=0, **teacher_weights
    )
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    with create_session_factory(engine)() as session:
        user = User(username="lead", password_hash="x", role=Role.reviewer)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user, "e2e")
        session.commit()
    frames = synth_sequence(seed=5, length=14, params=SIZE)
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        run = client.post(
            "/api/v1/sequences", json={"name": "run 5", "voltage_v": 21.0}, headers=auth(token)
        ).json()
        files = [
            ("files", (f"f{i:02d}.png", cv2.imencode(".png", f.image)[1].tobytes(), "image/png"))
            for i, f in enumerate(frames)
        ]
        stored = client.post(
            "/api/v1/frames", files=files, data={"sequence_id": str(run["id"])}, headers=auth(token)
        ).json()["stored"]
        ids = [f["id"] for f in stored]

        teacher = client.post(
            "/api/v1/teacher/runs", json={"sequence_id": run["id"]}, headers=auth(token)
        ).json()
        assert wait_for_job(client, teacher["job_id"], token, 120)["status"] == "succeeded"
        proposal = client.get(f"/api/v1/frames/{ids[0]}/proposal", headers=auth(token)).json()
        assert proposal["source"] == "teacher"
        click = client.post(
            f"/api/v1/frames/{ids[0]}/segment",
            headers=auth(token),
            json={"points": [{"x": 96, "y": 60}]},
        ).json()
        assert click["embedding"] in ("memory", "disk")  # the teacher cached it

        # The reviewer accepts one proposal and corrects the others with the true masks;
        # two frames get manual keypoints and form the validation split.
        accepted = client.put(
            f"/api/v1/frames/{ids[0]}/label",
            headers=auth(token),
            json={"status": "accepted", "base_revision": 0},
        )
        assert accepted.status_code == 200
        for frame_id, truth in zip(ids[1:12], frames[1:12], strict=True):
            body = corrected_label(truth.mask)
            assert (
                client.put(
                    f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token)
                ).status_code
                == 200
            )
        for frame_id, truth in zip(ids[10:12], frames[10:12], strict=True):
            points = [[float(x), float(y)] for x, y in truth.keypoints]
            client.put(
                f"/api/v1/frames/{frame_id}/validation-keypoints",
                json={"keypoints": points},
                headers=auth(token),
            )

        train = client.post(
            "/api/v1/student/train", json={"epochs": 2, "size": "light"}, headers=auth(token)
        )
        assert train.status_code == 202, train.text
        job = wait_for_job(client, train.json()["job_id"], token, 300)
        assert job["status"] == "succeeded", job["error"]
        models = client.get("/api/v1/models", headers=auth(token)).json()
        assert len(models) == 1
        version = models[0]
        assert version["train_label_count"] == 10 and version["metrics"]["validation_frames"] == 2
        assert "mIoU" in version["metrics"] and len(version["curve"]) == 2
        folder = settings.home / "models" / version["name"]  # pruned: weights, metrics, curve
        assert (folder / "model.safetensors").is_file() and (folder / "curve.json").is_file()
        assert not (folder / "training_state.pt").exists()
        verdict = job["result"]["gate"]
        assert version["is_promoted"] == verdict["promote"] and verdict["reason"]
        if not verdict["promote"]:  # two epochs rarely beat the teacher: promote by hand
            refused = client.post(f"/api/v1/models/{version['id']}/promote", headers=auth(token))
            assert refused.status_code == 409, refused.text
            forced = client.post(
                f"/api/v1/models/{version['id']}/promote",
                params={"force": "true"},
                headers=auth(token),
            )
            assert forced.status_code == 200 and forced.json()["is_promoted"]
        student_jobs = client.get(
            "/api/v1/jobs", params={"kind": "student"}, headers=auth(token)
        ).json()["items"]
        assert len(student_jobs) == 1
        assert wait_for_job(client, student_jobs[0]["id"], token, 120)["status"] == "succeeded"
        unreviewed = client.get(f"/api/v1/frames/{ids[13]}", headers=auth(token)).json()
        assert unreviewed["proposal"]["source"] == "teacher"  # never measured better: not shown
        listed = client.get(f"/api/v1/frames/{ids[13]}/proposals", headers=auth(token)).json()
        assert {p["source"] for p in listed["items"]} == {"teacher", "student"}
        assert unreviewed["uncertainty"] is not None
        assert set(unreviewed["uncertainty_components"]) >= {"student_uncertainty", "disagreement"}
        figures = client.get("/api/v1/metrics", headers=auth(token)).json()
        assert figures["student"][0]["train_label_count"] == 10

        export = client.get("/api/v1/export", params={"format": "masks"}, headers=auth(token))
        assert export.status_code == 200
        zipfile.ZipFile(io.BytesIO(export.content)).extractall(tmp_path / "dataset")

    env = dict(os.environ, WELDPOOL_HOME=str(tmp_path / "cli-home"))
    trained = subprocess.run(
        [
            sys.executable,
            "-m",
            "app",
            "train",
            str(tmp_path / "dataset"),
            "--out",
            str(tmp_path / "model"),
            "--epochs",
            "1",
            "--model",
            "light",
        ],
        env=env,
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert trained.returncode == 0, trained.stderr[-2000:]
    assert (tmp_path / "model" / "config.json").exists()


def test_killed_worker_during_training(tmp_path: Path, database_url: str) -> None:
    settings = make_settings(tmp_path / "home", database_url=database_url, retrain_every=0)
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    factory = create_session_factory(engine)
    with factory() as session:
        user = User(username="lead", password_hash="x", role=Role.reviewer)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user, "kill")
        session.commit()
    with TestClient(create_app(settings)) as client:  # no worker in this process
        frames = synth_sequence(seed=2, length=6, params=SIZE)
        files = [
            ("files", (f"k{i}.png", cv2.imencode(".png", f.image)[1].tobytes(), "image/png"))
            for i, f in enumerate(frames)
        ]
        ids = [
            f["id"]
            for f in client.post("/api/v1/frames", files=files, headers=auth(token)).json()[
                "stored"
            ]
        ]
        for frame_id, truth in zip(ids, frames, strict=True):
            client.put(
                f"/api/v1/frames/{frame_id}/label",
                headers=auth(token),
                json=corrected_label(truth.mask),
            )
        long_job = client.post(
            "/api/v1/student/train", json={"epochs": 200, "size": "light"}, headers=auth(token)
        ).json()["job_id"]

    env = dict(
        os.environ,
        WELDPOOL_HOME=str(settings.home),
        WELDPOOL_DATABASE_URL=settings.resolved_database_url,
        WELDPOOL_QUEUE_NAME=settings.queue_name,
        WELDPOOL_JOB_HEARTBEAT_S="0.5",
    )

    def start_worker() -> subprocess.Popen[bytes]:
        return subprocess.Popen(
            [sys.executable, "-m", "app", "worker"],
            env=env,
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

    worker = start_worker()

    def job(job_id: int) -> Job:
        with factory() as session:
            return session.get_one(Job, job_id)

    try:
        wait_for(lambda: job(long_job).progress > 0.05, timeout=180, interval=0.2)
        worker.send_signal(signal.SIGKILL)
        worker.wait()
        work = settings.home / "models" / f".work-job{long_job}"
        assert job(long_job).status == JobStatus.running and work.exists()

        worker = start_worker()
        wait_for(lambda: job(long_job).status == JobStatus.failed, timeout=60)
        assert "stopped without finishing" in (job(long_job).error or "")
        with factory() as session:
            assert session.query(ModelVersion).count() == 0  # nothing half-written
            user = session.query(User).one()
            queue = JobQueue(settings, factory)
            next_job = create_job(
                session, queue, "train_student", {"epochs": 1, "size": "light"}, user
            ).id
        wait_for(lambda: job(next_job).status.finished, timeout=300, interval=0.5)
        assert job(next_job).status == JobStatus.succeeded, job(next_job).error
        assert not work.exists()  # the killed job's work folder is gone
        with factory() as session:
            version = session.query(ModelVersion).one()
        assert (settings.home / version.checkpoint_path).is_dir()
    finally:
        if worker.poll() is None:
            worker.kill()
            worker.wait()
