"""The store's one collector: a file is removed only when no committed row names it and
nobody claimed it within the grace period; a claim made while the collector looks is seen."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import pytest

from app.storage import LocalStorage, Storage
from app.storage import local as storage_module


def _stored(storage: Storage, data: bytes) -> str:
    return storage.put(data, hashlib.sha256(data).hexdigest(), ".png").path


def _age(storage: Storage, relative: str, seconds: float) -> None:
    then = time.time_ns() - int(seconds * 1e9)
    os.utime(storage.absolute(relative), ns=(then, then))


def test_collect_removes_only_unnamed_files_whose_claim_lapsed(tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path, grace_s=100)
    old, fresh, named = (_stored(storage, bytes([i]) * 10) for i in range(3))
    _age(storage, old, 101)
    _age(storage, named, 101)
    assert storage.collect([old, fresh, named], in_use={named}) == [old]
    assert not storage.absolute(old).exists()
    assert storage.absolute(fresh).exists() and storage.absolute(named).exists()
    assert list(storage.tmp.glob("*.collect")) == []


def test_reusing_stored_content_claims_it(tmp_path: Path) -> None:
    """put and stage of content already there refresh its claim, so a deletion that commits
    before the reusing row leaves the file."""
    storage = LocalStorage(tmp_path, grace_s=100)
    data = b"shared content"
    relative = _stored(storage, data)
    _age(storage, relative, 1000)
    again = storage.stage(data, hashlib.sha256(data).hexdigest(), ".png")
    assert again.temporary is None  # not written again: claimed
    assert storage.collect([relative], in_use=()) == []
    _age(storage, relative, 1000)
    assert storage.put(data, hashlib.sha256(data).hexdigest(), ".png").created is False
    assert storage.collect([relative], in_use=()) == []
    assert storage.absolute(relative).read_bytes() == data


def test_a_claim_made_while_the_collector_looks_keeps_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The collector moves a file aside, then reads its claim: an upload that claimed it just
    before is seen (the file goes back); one that claims it while it is aside finds no file
    and writes it again."""
    storage = LocalStorage(tmp_path, grace_s=100)
    data = b"raced content"
    digest = hashlib.sha256(data).hexdigest()
    relative = _stored(storage, data)
    _age(storage, relative, 1000)
    real_rename = os.rename

    def claim_then_rename(source: str | Path, target: str | Path) -> None:
        storage._claim(storage.absolute(relative))  # the upload claims it first
        real_rename(source, target)

    monkeypatch.setattr(storage_module.os, "rename", claim_then_rename)
    assert storage.collect([relative], in_use=()) == []
    assert storage.absolute(relative).read_bytes() == data

    _age(storage, relative, 1000)
    written: list[bool] = []

    def rename_then_claim(source: str | Path, target: str | Path) -> None:
        real_rename(source, target)
        written.append(storage.put(data, digest, ".png").created)  # finds it gone: writes it

    monkeypatch.setattr(storage_module.os, "rename", rename_then_claim)
    assert storage.collect([relative], in_use=()) == [relative]  # the old copy
    assert written == [True] and storage.absolute(relative).read_bytes() == data


def test_a_claimed_file_is_never_moved_aside_even_for_a_moment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file claimed within the grace period is left where it is: a reader just handed it (a
    video probed after its upload claimed the stored copy) found it gone while the collector
    had it aside (the race test's 500)."""
    storage = LocalStorage(tmp_path, grace_s=100)
    relative = _stored(storage, b"just claimed")
    moved: list[object] = []
    monkeypatch.setattr(storage_module.os, "rename", lambda *args: moved.append(args))
    assert storage.collect([relative], in_use=()) == []
    assert moved == []


def test_discard_keeps_a_file_another_writer_claimed_since(tmp_path: Path) -> None:
    """An aborted write removes the files it created, unless another writer claimed them
    after it (that writer's row may be about to commit)."""
    storage = LocalStorage(tmp_path, grace_s=100)
    mine = storage.put(b"only mine", hashlib.sha256(b"only mine").hexdigest(), ".png")
    theirs = storage.put(b"also theirs", hashlib.sha256(b"also theirs").hexdigest(), ".png")
    assert mine.created and theirs.created
    storage.put(b"also theirs", hashlib.sha256(b"also theirs").hexdigest(), ".png")  # claim
    assert storage.discard([mine, theirs]) == 1
    assert not storage.absolute(mine.path).exists()
    assert storage.absolute(theirs.path).read_bytes() == b"also theirs"


def test_sweep_puts_back_a_file_a_dead_collector_left_aside(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = LocalStorage(tmp_path, grace_s=100)
    relative = _stored(storage, b"named by a row")
    storage.tmp.mkdir(exist_ok=True)
    aside = storage.tmp / f"{relative.replace('/', '~')}~deadbeef.collect"
    os.rename(storage.absolute(relative), aside)
    assert storage.sweep_orphans(["frames"], known={relative}) == []
    assert aside.exists()  # moved aside just now: a live collector may be looking at it
    real_time = time.time
    monkeypatch.setattr(storage_module.time, "time", lambda: real_time() + 61)
    assert storage.sweep_orphans(["frames"], known={relative}) == []
    assert storage.absolute(relative).read_bytes() == b"named by a row"
    assert list(storage.tmp.glob("*.collect")) == []


def test_a_lost_file_is_one_missing_file_error_and_lost_names_it(tmp_path: Path) -> None:
    from app.core.errors import MissingFile, http_status_of

    storage = LocalStorage(tmp_path / "home")
    kept, gone = _stored(storage, b"kept"), _stored(storage, b"gone")
    assert storage.existing(kept).read_bytes() == b"kept"
    (storage.home / gone).unlink()
    with pytest.raises(MissingFile) as raised:
        storage.existing(gone)
    assert raised.value.path == gone and isinstance(raised.value, FileNotFoundError)
    assert http_status_of(raised.value) == 409
    assert raised.value.message == (
        f"The stored file {gone} is missing; run `weldpool doctor` to list the lost files and "
        "what restores each."
    )
    assert storage.lost([kept, gone, "../outside.png", "models/none"]) == {
        gone,
        "../outside.png",
        "models/none",
    }
