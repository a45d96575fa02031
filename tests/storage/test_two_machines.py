"""A web process and a worker that share nothing but the three URLs: the real PostgreSQL, the
real Redis and a bucket on the S3-protocol server, each with a home folder of its own. The
teacher, training, a student's proposals and an export run end to end across them; and a web
process killed with SIGKILL mid-upload leaves no row whose object is missing."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import cv2
import httpx
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Frame, ModelVersion, Proposal, Role, User
from app.core.schema import migrate
from app.core.security import issue_token
from app.main import create_app
from tests.helpers import REPO, auth, corrected_label, make_settings, wait_for, wait_for_job
from tests.s3 import bucket_keys
from weldpool_core.synth import SynthParams, synth_sequence

pytestmark = pytest.mark.slow
SIZE = SynthParams(width=160, height=112)


def _env(settings: Settings, home: Path) -> dict[str, str]:
    """The worker's environment: the three URLs and the teacher's weights, its own home."""
    env = dict(os.environ)
    env.update(
        WELDPOOL_HOME=str(home),
        WELDPOOL_DATABASE_URL=settings.resolved_database_url,
        WELDPOOL_QUEUE_URL=str(settings.queue_url),
        WELDPOOL_QUEUE_NAME=settings.queue_name,
        WELDPOOL_STORAGE_URL=str(settings.storage_url),
        WELDPOOL_S3_ENDPOINT_URL=str(settings.s3_endpoint_url),
        WELDPOOL_DINO=settings.dino,
        WELDPOOL_SAM2=settings.sam2,
        WELDPOOL_DINO_INPUT_SIZE=str(settings.dino_input_size),
        WELDPOOL_DEVICE="cpu",
        WELDPOOL_RETRAIN_EVERY="0",
        WELDPOOL_JOB_HEARTBEAT_S="0.5",
    )
    return env


def _token(settings: Settings) -> str:
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    with create_session_factory(engine)() as session:
        user = User(username="lead", password_hash="x", role=Role.admin)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user, "two machines")
        session.commit()
    engine.dispose()
    return token


def test_web_and_worker_with_no_shared_disk(
    tmp_path: Path,
    postgres_url: str,
    redis_url: str,
    s3_url: str,
    s3_endpoint: str,
    teacher_weights: dict[str, object],
) -> None:
    settings = make_settings(
        tmp_path / "web",
        database_url=postgres_url,
        queue_url=redis_url,
        storage_url=s3_url,
        s3_endpoint_url=s3_endpoint,
        retrain_every=0,
        **teacher_weights,
    )
    token = _token(settings)
    worker_home = tmp_path / "worker"
    log = open(tmp_path / "worker.log", "w")  # noqa: SIM115
    worker = subprocess.Popen(
        [sys.executable, "-m", "app", "worker"],
        env=_env(settings, worker_home),
        cwd=REPO,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    frames = synth_sequence(seed=7, length=10, params=SIZE)
    try:
        with TestClient(create_app(settings)) as client:  # no embedded worker
            files = [
                ("files", (f"f{i}.png", cv2.imencode(".png", f.image)[1].tobytes(), "image/png"))
                for i, f in enumerate(frames)
            ]
            run = client.post(
                "/api/v1/sequences", json={"name": "cell 2"}, headers=auth(token)
            ).json()
            stored = client.post(
                "/api/v1/frames",
                files=files,
                data={"sequence_id": str(run["id"])},
                headers=auth(token),
            ).json()
            ids = [f["id"] for f in stored["stored"]]
            keys = bucket_keys(s3_endpoint, s3_url, "frames/")
            assert len(keys) == len(frames)  # in the bucket before the upload answered

            teacher = client.post(
                "/api/v1/teacher/runs", json={"sequence_id": run["id"]}, headers=auth(token)
            ).json()
            done = wait_for_job(client, teacher["job_id"], token, 180)
            assert done["status"] == "succeeded", (done["error"], _tail(tmp_path))
            # The worker read the frames from the bucket and wrote its masks there; the web
            # process serves one it never wrote.
            assert (worker_home / "frames").is_dir()
            assert any(k.startswith("artefacts/") for k in bucket_keys(s3_endpoint, s3_url))
            mask = client.get(f"/api/v1/frames/{ids[0]}/proposal/mask.png", headers=auth(token))
            assert mask.status_code == 200 and mask.content.startswith(b"\x89PNG")

            for frame_id, truth in zip(ids[:7], frames[:7], strict=True):  # 3 left for the student
                saved = client.put(
                    f"/api/v1/frames/{frame_id}/label",
                    json=corrected_label(truth.mask),
                    headers=auth(token),
                )
                assert saved.status_code == 200, saved.text
            train = client.post(
                "/api/v1/student/train", json={"epochs": 1, "size": "light"}, headers=auth(token)
            )
            done = wait_for_job(client, train.json()["job_id"], token, 300)
            assert done["status"] == "succeeded", (done["error"], _tail(tmp_path))
            name = done["result"]["name"]
            weights = bucket_keys(s3_endpoint, s3_url, f"models/{name}/")
            assert f"models/{name}/model.safetensors" in weights
            assert not (settings.home / "models" / name).exists()  # never on the web's disk …
            forced = client.post(
                f"/api/v1/models/{done['result']['model_version_id']}/promote",
                params={"force": "true"},
                headers=auth(token),
            )
            assert forced.status_code == 200, forced.text
            engine = create_db_engine(settings.resolved_database_url)
            with create_session_factory(engine)() as session:

                def student_proposals() -> int:
                    return session.scalar(
                        sa.select(sa.func.count(Proposal.id)).where(Proposal.source == "student")
                    )

                wait_for(lambda: student_proposals() >= 3, timeout=180, interval=0.5)
                version = session.scalars(sa.select(ModelVersion)).one()
                from app.storage import open_storage

                folder = open_storage(settings).folder(version.checkpoint_path)
                assert folder is not None and (folder / "model.safetensors").is_file()  # … fetched
            engine.dispose()

            export = client.post(
                "/api/v1/exports", json={"format": "masks"}, headers=auth(token)
            ).json()
            done = wait_for_job(client, export["job_id"], token, 120)
            assert done["status"] == "succeeded", (done["error"], _tail(tmp_path))
            assert f"exports/{export['job_id']}.zip" in bucket_keys(s3_endpoint, s3_url)
            download = client.get(f"/api/v1/exports/{export['job_id']}", headers=auth(token))
            assert download.status_code == 200
            names = zipfile.ZipFile(io.BytesIO(download.content)).namelist()
            assert sum(n.startswith("masks/") for n in names) == 7
    finally:
        worker.send_signal(signal.SIGTERM)
        try:
            worker.wait(timeout=30)
        except subprocess.TimeoutExpired:
            worker.kill()
        log.close()
    assert not (worker_home / "weldpool.sqlite3").exists()  # the worker shares only the URLs


def _tail(tmp_path: Path) -> str:
    return (tmp_path / "worker.log").read_text()[-3000:]


def test_a_web_process_killed_mid_upload_leaves_no_row_without_its_object(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    from tests.web.server import free_port

    home, port = tmp_path / "home", free_port()
    settings = make_settings(home, storage_url=s3_url, s3_endpoint_url=s3_endpoint)
    token = _token(settings)
    env = dict(
        os.environ,
        WELDPOOL_HOME=str(home),
        WELDPOOL_STORAGE_URL=s3_url,
        WELDPOOL_S3_ENDPOINT_URL=s3_endpoint,
    )
    server = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--port", str(port), "--no-worker"],
        env=env,
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    base = f"http://127.0.0.1:{port}"
    rng_frames = synth_sequence(seed=11, length=48, params=SynthParams(width=640, height=400))
    bodies = [cv2.imencode(".png", f.image)[1].tobytes() for f in rng_frames]
    answered: list[int] = []

    def upload() -> None:
        with httpx.Client(base_url=base, headers=auth(token), timeout=30) as http:
            for start in range(0, len(bodies), 4):
                files = [
                    ("files", (f"k{start + i}.png", body, "image/png"))
                    for i, body in enumerate(bodies[start : start + 4])
                ]
                try:
                    http.post("/api/v1/frames", files=files)
                except httpx.HTTPError:
                    return
                answered.append(start)

    try:
        wait_for(lambda: _up(base), timeout=60, interval=0.2)
        uploader = threading.Thread(target=upload)
        uploader.start()
        wait_for(lambda: len(answered) >= 3, timeout=60, interval=0.01)
        server.send_signal(signal.SIGKILL)  # mid-upload: later requests are in flight
        server.wait()
        uploader.join(timeout=60)
    finally:
        if server.poll() is None:
            server.kill()
    assert len(answered) < len(bodies) // 4  # it died before the upload finished
    engine = create_db_engine(settings.resolved_database_url)
    with create_session_factory(engine)() as session:
        sizes = dict(session.execute(sa.select(Frame.path, Frame.size_bytes)).all())
    engine.dispose()
    assert len(sizes) >= 12
    objects = bucket_keys(s3_endpoint, s3_url, "frames/")
    assert set(sizes) <= set(objects)  # every row's object is there …
    assert all(objects[path] == size for path, size in sizes.items())  # … whole


def _up(base: str) -> bool:
    try:
        return httpx.get(f"{base}/api/v1/health", timeout=1).status_code == 200
    except httpx.HTTPError:
        return False
