"""An uploaded import is written once: its multipart part spooled straight to a named file in
the store's scratch folder, then moved (renamed) under ``imports/``, never copied; on an
object store the same, then published to the bucket."""

from __future__ import annotations

import asyncio
import io
import os
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from app.frames.multipart import StreamedForm
from app.imports import uploads
from app.imports.uploads import IMPORTS_DIR, keep_upload, upload_name
from app.storage import LocalStorage, Storage, open_storage
from tests.helpers import make_settings
from tests.s3 import bucket_keys

DATA = bytes(range(256)) * 5000  # 1.28 MB: past any in-memory spool


async def _chunks(body: bytes) -> AsyncIterator[bytes]:
    for start in range(0, len(body), 65_537):
        yield body[start : start + 65_537]


def _spooled(storage: Storage) -> tuple[StreamedForm, Any]:
    """A one-file form read with the store's scratch folder as its spool, and its file."""
    body = (
        b'--b\r\nContent-Disposition: form-data; name="file"; filename="set.zip"\r\n\r\n'
        + DATA
        + b"\r\n--b--\r\n"
    )
    files: list[Any] = []
    form = StreamedForm(
        lambda *file: files.append(file[2]), max_files=1, max_fields=4, spool_dir=storage.scratch()
    )
    asyncio.run(form.read("multipart/form-data; boundary=b", _chunks(body)))
    return form, files[0]


def _no_copy(*args: Any) -> None:
    raise AssertionError("the upload was copied")


def test_a_spooled_import_is_moved_into_place_not_copied(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = LocalStorage(tmp_path)
    form, spooled = _spooled(storage)
    spool = Path(spooled.name)
    assert spool.parent == storage.scratch() and spool.suffix == ".part"  # swept if orphaned
    inode = os.stat(spool).st_ino
    monkeypatch.setattr(uploads.shutil, "copyfileobj", _no_copy)
    name = keep_upload(storage, spooled, ".zip")
    kept = storage.local(upload_name(name))
    assert kept.read_bytes() == DATA and os.stat(kept).st_ino == inode  # the spool itself
    form.close()
    assert kept.read_bytes() == DATA  # closing the form leaves the moved file
    assert list(storage.scratch().iterdir()) == []


def test_a_form_closed_unmoved_leaves_no_spool(tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path)
    form, spooled = _spooled(storage)
    assert spooled.read() == DATA
    form.close()
    assert spooled.closed and list(storage.scratch().iterdir()) == []


def test_an_upload_in_memory_or_elsewhere_is_copied(tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path / "home")
    name = keep_upload(storage, io.BytesIO(DATA), ".zip")
    assert storage.local(upload_name(name)).read_bytes() == DATA
    elsewhere = tmp_path / "elsewhere.part"
    elsewhere.write_bytes(DATA)
    with open(elsewhere, "rb") as source:
        again = keep_upload(storage, source, ".zip")
    assert storage.local(upload_name(again)).read_bytes() == DATA and elsewhere.exists()


def test_on_an_object_store_the_moved_upload_is_published(
    tmp_path: Path, s3_endpoint: str, s3_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = open_storage(make_settings(tmp_path, storage_url=s3_url, s3_endpoint_url=s3_endpoint))
    form, spooled = _spooled(storage)
    monkeypatch.setattr(uploads.shutil, "copyfileobj", _no_copy)
    name = keep_upload(storage, spooled, ".zip")
    monkeypatch.undo()  # shutil's own again (the download below copies)
    form.close()
    assert bucket_keys(s3_endpoint, s3_url, IMPORTS_DIR) == {upload_name(name): len(DATA)}
    storage.local(upload_name(name)).unlink()  # another machine: fetched from the bucket
    assert storage.existing(upload_name(name)).read_bytes() == DATA
