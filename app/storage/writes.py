"""The steps both backends share, written once: the content-addressed name, a batch staged in
parts, a stream hashed into a temporary, and the collector's two rules (an aborted write takes
back only its own files; a deletion's files go once nobody claimed them within the grace)."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from concurrent.futures import Executor, wait
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, TypeVar

from app.storage.protocol import CHUNK, StagedFile, StoredFile, Unclaimed

if TYPE_CHECKING:
    from app.storage.protocol import Storage

DISK_TASKS = 8
"""Tasks a batch of writes and flushes is split into (``stage_many``, ``install_many``): as
many as the disk threads, each writing its files one after another."""
_T = TypeVar("_T")


def best_effort(what: str, action: Callable[[], object]) -> None:
    """Tidying after the outcome is settled (a commit made, or an error being raised): a
    failure is logged, never raised, so it neither fails what succeeded nor hides the first
    error; the collector or the day's pruning finishes it."""
    try:
        action()
    except Exception as exc:
        import structlog

        structlog.get_logger(__name__).warning("storage.tidy_failed", what=what, error=str(exc))


def content_path(area: str, sha256: str, extension: str) -> str:
    """Where content with this hash lives in ``area`` (``frames/ab/cd/abcd….png``)."""
    return f"{area}/{sha256[:2]}/{sha256[2:4]}/{sha256}{extension}"


def parts(items: Sequence[_T], count: int) -> list[Sequence[_T]]:
    """``items`` in at most ``count`` consecutive parts of nearly equal length."""
    size = -(-len(items) // count) if items else 1
    return [items[at : at + size] for at in range(0, len(items), size)]


def stage_all(
    store: Storage,
    items: Sequence[tuple[bytes, str, str]],
    area: str,
    executor: Executor | None,
) -> list[StagedFile]:
    """``store.stage`` for many ``(data, sha256, extension)``, in ``executor``'s threads when
    given (``DISK_TASKS`` parts); if any fails, the others are unstaged and its error raised."""
    if executor is None:
        staged: list[StagedFile] = []
        try:
            for item in items:
                staged.append(store.stage(*item, area))
        except BaseException:
            store.unstage(staged)
            raise
        return staged
    futures = [
        executor.submit(stage_all, store, part, area, None) for part in parts(items, DISK_TASKS)
    ]
    wait(futures)
    errors = [e for f in futures if (e := f.exception()) is not None]
    if errors:
        store.unstage(s for f in futures if f.exception() is None for s in f.result())
        raise errors[0]
    return [staged for f in futures for staged in f.result()]


def copy_hashed(source: BinaryIO, temporary: Path) -> tuple[str, int]:
    """Copy a stream into ``temporary`` in chunks, hashing it on the way (``put_file`` flushes
    it); returns (sha256, size). The temporary goes if the copy fails."""
    digest, size = hashlib.sha256(), 0
    try:
        with open(temporary, "wb") as handle:
            while chunk := source.read(CHUNK):
                digest.update(chunk)
                size += len(chunk)
                handle.write(chunk)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return digest.hexdigest(), size


def discard_created(
    files: Iterable[StoredFile],
    in_use: Collection[str],
    remove_if: Callable[[str, Unclaimed], bool],
) -> int:
    """Remove the files an aborted write created, except those a committed row names or
    another writer claimed since (their claim time is no longer the one this write put);
    returns how many went."""
    return sum(
        remove_if(stored.path, stored.claimed_ns.__eq__)
        for stored in files
        if stored.created and stored.path not in in_use
    )


def collect_unclaimed(
    paths: Iterable[str],
    in_use: Collection[str],
    grace_s: float,
    remove_if: Callable[[str, Unclaimed], bool],
) -> list[str]:
    """Remove the files of ``paths`` no committed row names and nobody claimed within
    ``grace_s``; returns those removed."""
    cutoff = time.time_ns() - int(grace_s * 1e9)
    return [
        path for path in paths if path not in in_use and remove_if(path, lambda ns: ns < cutoff)
    ]
