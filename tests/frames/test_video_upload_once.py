"""An uploaded video is written once: its multipart part spooled straight into the store's
scratch folder and hashed on the way, then renamed under its content name (``put_file``), never
copied; the same content twice is stored once, and a refused or failed upload leaves no spool.
On an object store the spool is uploaded once and becomes the cached copy."""

from __future__ import annotations

import asyncio
import hashlib
import os
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Role
from app.frames import multipart
from app.frames.multipart import StreamedForm
from app.storage import LocalStorage, Storage, local, open_storage
from app.storage.spool import ScratchSpool, put_upload
from tests.helpers import auth, make_settings, write_video
from tests.s3 import bucket_keys


@pytest.fixture
def token(make_user: Any) -> str:
    return make_user("filmmaker", Role.annotator)[1]


@pytest.fixture
def spools(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Every spool the forms make from now on: its path and inode."""
    made: dict[str, int] = {}

    class Recorded(ScratchSpool):
        def __init__(self, folder: Path, *, hashed: bool = False) -> None:
            super().__init__(folder, hashed=hashed)
            made[str(self.name)] = os.fstat(self.fileno()).st_ino

    monkeypatch.setattr(multipart, "ScratchSpool", Recorded)
    return made


def _no_copy(*args: Any) -> None:
    raise AssertionError("the upload was copied")


def _upload(client: TestClient, token: str, path: Path, **data: str) -> Any:
    with open(path, "rb") as handle:
        return client.post(
            "/api/v1/videos",
            files={"file": (path.name, handle, "video/avi")},
            data=data,
            headers=auth(token),
        )


def _files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()] if folder.is_dir() else []


def test_an_uploaded_video_is_renamed_into_place_not_copied(
    client: TestClient,
    token: str,
    settings: Settings,
    tmp_path: Path,
    spools: dict[str, int],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(local, "copy_hashed", _no_copy)  # put_stream's copy
    video = write_video(tmp_path / "run.avi", 40)
    data = video.read_bytes()
    response = _upload(client, token, video)
    assert response.status_code == 202, response.text
    body = response.json()["video"]
    assert body["sha256"] == hashlib.sha256(data).hexdigest() and body["size_bytes"] == len(data)
    stored = settings.home / "videos" / body["sha256"][:2] / body["sha256"][2:4]
    (path,) = _files(stored)
    assert path.read_bytes() == data
    ((spool, inode),) = spools.items()
    assert Path(spool).parent == settings.home / "tmp"  # the store's scratch: one filesystem
    assert os.stat(path).st_ino == inode  # the spool itself, renamed
    assert _files(settings.home / "tmp") == []

    again = _upload(client, token, video)  # the same content: claimed, the new spool removed
    assert again.status_code == 202, again.text
    assert again.json()["video"]["sha256"] == body["sha256"]
    assert _files(settings.home / "videos") == [path] and os.stat(path).st_ino == inode
    assert len(spools) == 2 and _files(settings.home / "tmp") == []


def test_a_refused_or_failed_video_leaves_no_spool(
    client: TestClient,
    token: str,
    settings: Settings,
    tmp_path: Path,
    spools: dict[str, int],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fake = tmp_path / "fake.avi"
    fake.write_bytes(b"RIFF\0\0\0\0AVI but nothing a decoder can read" * 100)
    response = _upload(client, token, fake)  # renamed into place, then refused by the probe
    assert response.status_code == 400, response.text
    assert "readable frame" in response.json()["detail"] or "opened" in response.json()["detail"]
    not_video = tmp_path / "notes.avi"
    not_video.write_bytes(b"plain text, not a video")
    assert _upload(client, token, not_video).status_code == 400  # refused before storing
    good = write_video(tmp_path / "good.avi", 10)
    assert _upload(client, token, good, every_nth="0").status_code == 400
    assert _upload(client, token, good, sequence_id="77").status_code == 404
    assert len(spools) == 4
    assert _files(settings.home / "tmp") == [] and _files(settings.home / "videos") == []

    def broken(self: LocalStorage, temporary: Path, relative: str) -> Any:
        raise OSError("the disk is full")

    monkeypatch.setattr(LocalStorage, "_install", broken)
    with pytest.raises(OSError, match="disk is full"):  # the test client re-raises a 500
        _upload(client, token, good)
    assert _files(settings.home / "tmp") == [] and _files(settings.home / "videos") == []


async def _chunks(body: bytes) -> AsyncIterator[bytes]:
    for start in range(0, len(body), 65_537):
        yield body[start : start + 65_537]


def _spooled(storage: Storage, data: bytes) -> tuple[StreamedForm, Any]:
    """A one-file form read into the store's scratch folder, hashed, and its file."""
    body = (
        b'--b\r\nContent-Disposition: form-data; name="file"; filename="run.mp4"\r\n\r\n'
        + data
        + b"\r\n--b--\r\n"
    )
    files: list[Any] = []
    form = StreamedForm(
        lambda *file: files.append(file[2]),
        max_files=1,
        max_fields=4,
        spool_dir=storage.scratch(),
        hashed=True,
    )
    asyncio.run(form.read("multipart/form-data; boundary=b", _chunks(body)))
    return form, files[0]


def test_on_an_object_store_the_spool_is_uploaded_once_and_cached(
    tmp_path: Path, s3_endpoint: str, s3_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import app.storage.s3.bucket as s3
    import app.storage.s3.store as store

    monkeypatch.setattr(s3, "MULTIPART_BYTES", 5 * 1024 * 1024)  # S3's smallest part
    monkeypatch.setattr(store, "copy_hashed", _no_copy)  # put_stream's copy
    storage = open_storage(make_settings(tmp_path, storage_url=s3_url, s3_endpoint_url=s3_endpoint))
    data = os.urandom(6 * 1024 * 1024)
    sha256 = hashlib.sha256(data).hexdigest()
    form, spooled = _spooled(storage, data)
    assert spooled.sha256 == sha256 and spooled.size == len(data)
    inode = os.fstat(spooled.fileno()).st_ino
    stored, hashed, size = put_upload(storage, spooled, ".mp4", "videos")
    form.close()
    assert (hashed, size, stored.created) == (sha256, len(data), True)
    assert bucket_keys(s3_endpoint, s3_url, "videos/") == {stored.path: len(data)}
    objects = storage.objects  # type: ignore[attr-defined]
    head = objects.client.head_object(Bucket=objects.name, Key=objects.key(stored.path))
    assert "-" in head["ETag"]  # one multipart upload of the file
    cached = storage.local(stored.path)
    assert os.stat(cached).st_ino == inode  # the spool became the cached copy
    assert storage.existing(stored.path) == cached and storage.reads == 0  # type: ignore[attr-defined]
    assert _files(storage.scratch()) == []

    form, spooled = _spooled(storage, data)  # the same content: claimed, the spool not kept
    again, _, _ = put_upload(storage, spooled, ".mp4", "videos")
    form.close()
    assert again.path == stored.path and not again.created
    assert bucket_keys(s3_endpoint, s3_url, "videos/") == {stored.path: len(data)}
    assert cached.read_bytes() == data and _files(storage.scratch()) == []


def test_put_file_takes_the_file_whatever_happens(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = LocalStorage(tmp_path)
    first, second = storage.scratch() / "a.part", storage.scratch() / "b.part"
    for spool in (first, second):
        spool.write_bytes(b"weld")
    sha256 = hashlib.sha256(b"weld").hexdigest()
    inode = os.stat(first).st_ino
    stored = storage.put_file(first, sha256, ".mp4", "videos")
    assert stored.created and os.stat(storage.local(stored.path)).st_ino == inode
    again = storage.put_file(second, sha256, ".mp4", "videos")  # claimed; its file removed
    assert again.path == stored.path and not again.created and not second.exists()
    storage.local(stored.path).unlink()
    second.write_bytes(b"weld")
    monkeypatch.setattr(local, "_fsync", lambda path: _no_copy() if path == second else None)
    with pytest.raises(AssertionError):
        storage.put_file(second, sha256, ".mp4", "videos")
    assert _files(storage.scratch()) == [] and _files(tmp_path / "videos") == []
