"""Home as an object store's bounded read cache: files written or fetched land under home at
their relative path and are read from there; past WELDPOOL_STORAGE_CACHE_MB the least recently
used content files go (they are in the bucket), never one handed out within ``IN_USE_S``."""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from app.storage.local import LocalStorage
from app.storage.protocol import CHUNK, SHARED_AREAS
from app.storage.s3.bucket import Bucket

CONTENT_AREAS = ("frames", "videos", "artefacts")
"""Content-addressed areas: read through the cache by ``absolute`` and bounded by it."""
MARKER = "cache/storage-url"
"""In a home that is a store's cache: the store's URL (``check`` refuses a home holding files of
its own, which the cache would evict before any other machine saw them)."""
TOUCH_EVERY_S = 60.0
"""A cached file read again is marked recent at most once a minute (the cache's LRU order)."""
IN_USE_S = 600.0
"""The cache never evicts a file written, fetched or read within this long: a request or job
that was just handed its path is still reading it (the bound may be passed meanwhile)."""


class ObjectCache:
    """The cached copies of a bucket's files in a home folder (``files``, not flushed: the
    bucket holds the durable copy), kept to ``cache_bytes``."""

    def __init__(self, files: LocalStorage, bucket: Bucket, cache_bytes: int) -> None:
        self.files = files
        self.bucket = bucket
        self.cache_bytes = cache_bytes
        self.reads = 0
        """Objects read from the bucket (``bench/storage.py`` counts a click's)."""
        self._since_trim = 0
        self._lock = threading.Lock()

    def place(self, temporary: Path, relative: str) -> None:
        """Keep a written temporary as the cached copy of ``relative``."""
        final = self.files.home / relative
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(temporary, final)
        self._count(final.stat().st_size)

    def fetch(self, relative: str, path: Path) -> bool:
        """Stream an object into its cached copy at ``path`` (one GET); False when the bucket
        does not hold it."""
        body = self.bucket.get(relative)
        if body is None:
            return False
        self._receive(body, path)
        self.reads += 1  # counted once the copy is in place: a reader waiting on it finds it
        return True

    def _receive(self, body: BinaryIO, path: Path) -> None:
        """Stream a fetched object's body into ``path``, whole or not at all (through a
        temporary)."""
        temporary = self.files.temporary()
        try:
            with body, open(temporary, "wb") as handle:
                shutil.copyfileobj(body, handle, CHUNK)
            path.parent.mkdir(parents=True, exist_ok=True)
            os.replace(temporary, path)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        self._count(path.stat().st_size)

    def recent(self, path: Path) -> bool:
        """Whether this machine holds the cached copy at ``path``; if so it is marked recently
        used (at most once a minute)."""
        try:
            changed = path.stat().st_mtime
        except FileNotFoundError:
            return False
        if time.time() - changed > TOUCH_EVERY_S:
            with contextlib.suppress(FileNotFoundError):
                os.utime(path)
        return True

    def drop(self, relative: str) -> None:
        """Forget the cached copy of ``relative`` (its object went to the trash)."""
        (self.files.home / relative).unlink(missing_ok=True)

    def _count(self, size: int) -> None:
        with self._lock:
            self._since_trim += size
            due = self._since_trim > self.cache_bytes // 10
            if due:
                self._since_trim = 0
        if due:
            self.trim()

    def trim(self) -> int:
        """Remove the least recently used cached content files until the cache holds at
        most 80 % of its bound, never one used within ``IN_USE_S``; returns the bytes freed."""
        files = []
        for area in CONTENT_AREAS:
            root = self.files.home / area
            for path in root.rglob("*") if root.is_dir() else ():
                try:
                    info = path.stat()
                except FileNotFoundError:
                    continue
                if path.is_file():
                    files.append((info.st_mtime, info.st_size, path))
        total = sum(size for _, size, _ in files)
        if total <= self.cache_bytes:
            return 0
        freed, recent = 0, time.time() - IN_USE_S
        for changed, size, path in sorted(files):
            if total - freed <= 0.8 * self.cache_bytes or changed > recent:
                break
            path.unlink(missing_ok=True)
            freed += size
        return freed

    # --- whose cache home is -----------------------------------------------------------

    def is_cache_of(self, remote: str) -> bool:
        """Whether home is ``remote``'s cache: marked so, or marked now when it holds no
        shared files of its own (a fresh home)."""
        marker = self.files.home / MARKER
        with contextlib.suppress(FileNotFoundError):
            return marker.read_text().strip() == remote
        if any(any(files_under(self.files.home / area)) for area in SHARED_AREAS):
            return False
        self.mark(remote)
        return True

    def mark(self, remote: str) -> None:
        """Mark home as ``remote``'s cache (its own files are all in the bucket)."""
        marker = self.files.home / MARKER
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text(f"{remote}\n")

    def own_files(self) -> list[str]:
        """Home's shared files, as relative paths (what ``push`` uploads)."""
        home = self.files.home
        return [p.relative_to(home).as_posix() for a in SHARED_AREAS for p in files_under(home / a)]


def files_under(root: Path) -> Iterator[Path]:
    """The files under ``root`` (none when it is absent)."""
    return (p for p in root.rglob("*") if p.is_file()) if root.is_dir() else iter(())
