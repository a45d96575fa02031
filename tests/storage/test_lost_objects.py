"""On the object store (moto's S3 server), an object the bucket lost that this machine's cache
lacks is the same lost file as one gone from home: its frame's 409, an export that leaves the
frame out and lists it, and `weldpool doctor` naming it."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import boto3
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Frame, Role
from app.storage.s3 import parse_url
from tests.helpers import auth, corrected_label, image_bytes, make_settings, run_cli


@pytest.fixture
def settings(tmp_path: Path, database_url: str, s3_url: str, s3_endpoint: str) -> Settings:
    return make_settings(
        tmp_path / "home",
        database_url=database_url,
        storage_url=s3_url,
        s3_endpoint_url=s3_endpoint,
    )


def _drop_object(settings: Settings, relative: str) -> None:
    """The bucket loses the object (and this machine's cache its copy)."""
    bucket, prefix = parse_url(str(settings.storage_url))
    client = boto3.client("s3", endpoint_url=settings.s3_endpoint_url)
    client.delete_object(Bucket=bucket, Key=f"{prefix}/{relative}")
    (settings.home / relative).unlink()


def test_an_object_the_bucket_lost_is_its_frames_409_a_listed_skip_and_doctors_line(
    client: TestClient, settings: Settings, session_factory, make_user
) -> None:
    _, token = make_user("keeper", Role.reviewer)
    files = [
        ("files", (f"s{i}.png", image_bytes(64, 48, seed=80 + i), "image/png")) for i in (0, 1)
    ]
    stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    lost, kept = (f["id"] for f in stored)
    for frame_id in (lost, kept):
        mask = np.zeros((48, 64), bool)
        mask[10:30, 5 + 20 * (frame_id == kept) : 40] = True
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200, saved.text
    with session_factory() as session:
        path = session.get_one(Frame, lost).path
    _drop_object(settings, path)

    answer = client.get(f"/api/v1/frames/{lost}/image", headers=auth(token))
    assert answer.status_code == 409, answer.text
    assert answer.json()["detail"].startswith(f"Frame {lost}'s image ({path}) is missing")
    assert client.get(f"/api/v1/frames/{kept}/image", headers=auth(token)).status_code == 200

    export = client.get("/api/v1/export", params={"format": "coco"}, headers=auth(token))
    assert export.status_code == 200
    archive = zipfile.ZipFile(io.BytesIO(export.content))
    assert archive.testzip() is None
    assert [n for n in archive.namelist() if n.startswith("images/")] == [f"images/{kept:07d}.png"]
    assert archive.read("skipped.txt").decode().startswith(f"frame {lost}: Frame {lost}'s image")

    env = {
        "WELDPOOL_HOME": str(settings.home),
        "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
        "WELDPOOL_STORAGE_URL": str(settings.storage_url),
        "WELDPOOL_S3_ENDPOINT_URL": str(settings.s3_endpoint_url),
    }
    doctor = run_cli("doctor", env=env)
    assert doctor.returncode == 1, doctor.stderr
    assert doctor.stdout.splitlines() == [
        f"frame {lost}: image {path} is missing; upload the same image again (into any run) to "
        "restore it, or delete the frame"
    ]
    assert f"missing from {settings.storage_url}" in doctor.stderr
    assert "`weldpool storage push`" in doctor.stderr

    # Lost from the bucket but still in this machine's cache: served here, yet lost for every
    # other machine, so the doctor names it too (`weldpool storage push` restores it).
    with session_factory() as session:
        cached = session.get_one(Frame, kept).path
    bucket, prefix = parse_url(str(settings.storage_url))
    boto3.client("s3", endpoint_url=settings.s3_endpoint_url).delete_object(
        Bucket=bucket, Key=f"{prefix}/{cached}"
    )
    assert client.get(f"/api/v1/frames/{kept}/image", headers=auth(token)).status_code == 200
    again = run_cli("doctor", env=env)
    assert [line.split(":")[0] for line in again.stdout.splitlines()] == [
        f"frame {lost}",
        f"frame {kept}",
    ]


def test_a_trashed_object_is_not_lost_and_a_missing_key_is(
    tmp_path: Path, s3_url: str, s3_endpoint: str
) -> None:
    """``lost`` answers from one listing: a key in the trash (a reader puts it back) is held;
    a key in neither place is lost, and reading it is MissingFile (not a file of nothing)."""
    from app.core.config import StoreWaits
    from app.core.errors import MissingFile
    from app.storage.s3 import ObjectStorage

    waits = StoreWaits(connect_s=3.0, read_s=60.0, attempts=5)
    storage = ObjectStorage(tmp_path / "home", s3_url, 60.0, s3_endpoint, waits=waits)
    kept = storage.put(b"kept", "a" * 64, ".png").path
    trashed = storage.put(b"trashed", "b" * 64, ".png").path
    assert storage.trash.remove_if(trashed, lambda _ns: True)  # the collector trashed it
    assert storage.lost([kept, trashed, "frames/cc/cc/none.png"]) == {"frames/cc/cc/none.png"}
    assert storage.holds(kept) and not storage.holds("frames/cc/cc/none.png")  # one HEAD each
    with pytest.raises(MissingFile):
        storage.existing("frames/cc/cc/none.png")
    assert storage.existing(trashed).read_bytes() == b"trashed"  # put back by the read
