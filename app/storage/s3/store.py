"""``ObjectStorage``: the ``Storage`` whose shared files live in an S3-compatible bucket (AWS S3,
MinIO, Ceph), ``WELDPOOL_STORAGE_URL=s3://bucket/prefix``, composed over home as this machine's
bounded read cache.

The promises of ``app.storage.protocol`` hold on this backend too:

- **Written whole before its row is committed.** ``stage``/``put``/``put_file`` upload before
  they return (one PUT, or a multipart upload that S3 makes visible only once complete), in the
  caller's threads: the ingest's disk threads upload while the rest of the request is checked.
- **Content-addressed and claimed.** A claim is a copy of the object onto itself that sets its
  ``claimed`` metadata to now (``bucket.py``); a missing key means not stored.
- **Removed only by the collector, never from under a claim**: through the trash (``trash.py``).
- **A bounded local cache** (``cache.py``): files written or fetched land under home and are
  read from there. Reads and writes stream through files: no whole video or export in memory.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Collection, Iterable, Sequence
from concurrent.futures import Executor
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from app.core.errors import MissingFile
from app.storage.local import LocalStorage
from app.storage.protocol import SHARED_AREAS, StagedFile, StoredFile
from app.storage.s3.bucket import Bucket
from app.storage.s3.cache import CONTENT_AREAS, ObjectCache
from app.storage.s3.published import POOL, Published
from app.storage.s3.trash import Trash
from app.storage.writes import (
    collect_unclaimed,
    content_path,
    copy_hashed,
    discard_created,
    stage_all,
)

if TYPE_CHECKING:
    from app.core.config import Settings, StoreWaits


class ObjectStorage:
    """``Storage`` in a bucket, read through a ``LocalStorage`` of home (``files``) that it
    holds as its cache; the bucket's objects (``objects``), the cache's bound (``cache``), the
    collector (``trash``) and published folders (``published``) are its parts."""

    def __init__(
        self,
        home: Path,
        url: str,
        grace_s: float,
        endpoint_url: str | None = None,
        cache_bytes: int = 10 * 1024**3,
        region: str | None = None,
        *,
        waits: StoreWaits,
    ) -> None:
        self.objects = Bucket(url, endpoint_url, region or os.environ.get("AWS_REGION"), waits)
        self.files = LocalStorage(home, grace_s, durable=False)
        self.cache = ObjectCache(self.files, self.objects, cache_bytes)
        self.trash = Trash(self.objects, self.cache)
        self.published = Published(self.cache)
        self.home = self.files.home
        self.grace_s = grace_s
        self.remote: str | None = url
        self.cache.is_cache_of(url)  # marks a fresh home as this store's cache

    @classmethod
    def for_settings(cls, settings: Settings, waits: StoreWaits) -> ObjectStorage:
        """The instance's store (one per process, configuration and waits, so its cache
        accounting is shared)."""
        assert settings.storage_url
        return _store(
            settings.home.resolve(),
            settings.storage_url,
            settings.file_grace_s,
            settings.s3_endpoint_url,
            int(settings.storage_cache_mb * 1024 * 1024),
            waits,
        )

    @property
    def reads(self) -> int:
        """Objects read from the bucket by this store (``bench/storage.py`` counts a click's)."""
        return self.cache.reads

    def problem(self, *, named: bool = False) -> str | None:
        """Why the bucket cannot be used, in one sentence (one HEAD), or None; ``named``: the
        sentence names the store's URL (not for /health, which anyone may read)."""
        return self.objects.problem(
            f"The object store {self.remote}" if named else "The object store"
        )

    def check(self) -> None:
        """Raise a clear error when the bucket cannot be reached (at start-up), or home holds
        files of its own."""
        from app.core.errors import ConfigurationError

        problem = self.problem(named=True)
        if problem:
            raise ConfigurationError(problem)
        if not self.cache.is_cache_of(str(self.remote)):
            own = next((r.split("/", 1)[0] for r in self.cache.own_files()), "files")
            raise ConfigurationError(
                f"WELDPOOL_HOME ({self.home}) holds {own} of its own that {self.remote} may "
                "lack; upload them first with `weldpool storage push`, or give this machine an "
                "empty home."
            )

    def push(self) -> tuple[int, int]:
        """Upload every shared file of home the bucket lacks; returns (uploaded, already
        there). Home is then this store's cache."""
        return self.published.push(str(self.remote))

    # --- claims and writes: whole in the bucket before they return ---------------------

    def _claimed(self, relative: str) -> bool:
        """Claim an object: copy it onto itself with ``claimed`` = now."""
        return self.objects.stamped_copy(relative, relative)

    def _create_or_claim(self, data: bytes, relative: str) -> int | None:
        """Upload content unless its key exists; returns the new object's claim time, or None
        when the stored one was claimed."""
        for attempt in range(8):  # another writer's object can appear (or go) meanwhile
            claimed = self.objects.create(data, relative)
            if claimed is not None:
                return claimed
            if self._claimed(relative):
                return None
            time.sleep(min(1.0, 0.02 * 2**attempt))  # another writer's PUT is under way
        from botocore.exceptions import ClientError

        conflict = {
            "Error": {"Code": "ConditionalRequestConflict", "Message": "written meanwhile"},
            "ResponseMetadata": {"HTTPStatusCode": 409},
        }
        raise ClientError(conflict, "PutObject")  # the store's, for a while: an outage

    def _install(self, temporary: Path, relative: str) -> StoredFile:
        """Upload a written temporary unless the same content is stored (then claim it); the
        temporary becomes the cached copy either way."""
        try:
            if self._claimed(relative):
                self.cache.place(temporary, relative)
                return StoredFile(relative, created=False)
            claimed = time.time_ns()
            self.objects.upload_file(temporary, relative, claimed)
            self.cache.place(temporary, relative)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        return StoredFile(relative, created=True, claimed_ns=claimed)

    def put(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StoredFile:
        """Upload ``data`` unless the same content is stored (then claim it); cache a copy."""
        relative = content_path(area, sha256, extension)
        claimed = self._create_or_claim(data, relative)
        if claimed is None:
            return StoredFile(relative, created=False)
        self.cache.place(self.files.write_temporary(data), relative)
        return StoredFile(relative, created=True, claimed_ns=claimed)

    def stage(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StagedFile:
        """Upload new content now (in the caller's thread) and keep a cache copy aside;
        ``install_many`` only puts the copy in place, ``unstage`` withdraws the upload."""
        relative = content_path(area, sha256, extension)
        claimed = self._create_or_claim(data, relative)
        if claimed is None:
            return StagedFile(relative, None)
        return StagedFile(relative, self.files.write_temporary(data), uploaded_ns=claimed)

    def stage_many(
        self,
        items: Sequence[tuple[bytes, str, str]],
        area: str = "frames",
        executor: Executor | None = None,
    ) -> list[StagedFile]:
        return stage_all(self, items, area, executor)

    def unstage(self, staged: Iterable[StagedFile]) -> None:
        """Remove the cache copies and take back the uploads nobody claimed since."""
        items = list(staged)
        self.files.unstage(items)
        self.discard(
            StoredFile(s.relative, created=True, claimed_ns=s.uploaded_ns)
            for s in items
            if s.uploaded_ns
        )

    def install_many(
        self, staged: Sequence[StagedFile], executor: Executor | None = None
    ) -> list[StoredFile]:
        """Put staged copies in the cache (their uploads are complete already); one uploaded
        more than half a grace period ago is claimed anew."""
        results: list[StoredFile] = []
        try:
            for item in staged:
                if item.temporary is None:
                    results.append(StoredFile(item.relative, created=False))
                elif item.uploaded_ns and time.time_ns() - item.uploaded_ns < self.grace_s * 5e8:
                    self.cache.place(item.temporary, item.relative)
                    results.append(StoredFile(item.relative, True, item.uploaded_ns))
                else:
                    results.append(self._install(item.temporary, item.relative))
        except BaseException:
            self.discard(results)
            self.unstage(staged[len(results) :])
            raise
        return results

    def put_stream(
        self, source: BinaryIO, extension: str, area: str
    ) -> tuple[StoredFile, str, int]:
        temporary = self.files.temporary()
        sha256, size = copy_hashed(source, temporary)
        return self.put_file(temporary, sha256, extension, area), sha256, size

    def put_file(self, path: Path, sha256: str, extension: str, area: str) -> StoredFile:
        """Upload a file of ``scratch()`` once (in parts past ``MULTIPART_BYTES``) unless the
        same content is stored (then claim it); the file is renamed into the cache as its
        copy either way, and removed when this fails."""
        return self._install(path, content_path(area, sha256, extension))

    def write(self, relative: str, data: bytes) -> Path:
        """Write this machine's own file (a derived image under ``cache/``) atomically."""
        return self.files.write(relative, data)

    # --- reads through the cache ---------------------------------------------------------

    def absolute(self, relative: str) -> Path:
        """The cached copy of a stored file, fetched from the bucket when this machine has
        none (content areas; other paths are this machine's own)."""
        path = self.files.local(relative)
        if relative.split("/", 1)[0] in CONTENT_AREAS:
            self._ensure(relative, path)
        return path

    def fetch(self, relative: str) -> Path:
        path = self.files.local(relative)
        if relative.split("/", 1)[0] in SHARED_AREAS:
            self._ensure(relative, path)
        return path

    def existing(self, relative: str) -> Path:
        path = self.fetch(relative)
        if not path.is_file():
            raise MissingFile(relative)
        return path

    def fetch_ahead(self, paths: Iterable[str]) -> None:
        for relative in paths:
            POOL.submit(self._fetched_ahead, relative)

    def _fetched_ahead(self, relative: str) -> None:
        """A file read ahead: whatever goes wrong is met again by the read that wants it."""
        with contextlib.suppress(Exception):
            self.fetch(relative)

    def _ensure(self, relative: str, path: Path) -> None:
        if not self.cache.recent(path):
            self._download(relative, path)

    def _download(self, relative: str, path: Path) -> bool:
        """Fetch an object into the cache; a key found only in the trash is put back first.
        False when neither holds it (the caller then sees no file)."""
        if self.cache.fetch(relative, path):
            return True
        return self.trash.restore(relative) and self.cache.fetch(relative, path)

    def holds(self, relative: str) -> bool:
        """Whether the bucket holds the object ``relative`` (one HEAD; this machine's cached
        copy does not count: other machines cannot read it)."""
        return self.objects.claim_ns(relative) is not None

    def lost(self, paths: Iterable[str]) -> set[str]:
        """Those of ``paths`` the bucket holds neither under their key nor in the trash; a
        copy in this machine's cache does not count: other machines cannot read it."""
        return self.trash.lost(paths)

    def trim_cache(self) -> int:
        return self.cache.trim()

    # --- this machine's own paths: home's -------------------------------------------------

    def local(self, relative: str) -> Path:
        return self.files.local(relative)

    def relative(self, path: Path) -> str:
        return self.files.relative(path)

    def scratch(self) -> Path:
        return self.files.scratch()

    # --- shared files that are not content-addressed -----------------------------------

    def folder(self, relative: str) -> Path | None:
        return self.published.folder(relative)

    def has_folder(self, relative: str) -> bool:
        return self.objects.has_any(f"{relative}/") or self.files.has_folder(relative)

    def publish(self, relative: str, names: Iterable[str] | None = None) -> None:
        self.published.publish(relative, names)

    def unpublish(self, relative: str) -> None:
        self.published.unpublish(relative)

    def share(self, relative: str, path: Path) -> None:
        self.objects.upload_file(path, relative, time.time_ns())

    def pull(self, relative: str, path: Path) -> bool:
        return self.cache.fetch(relative, path)

    def prune_published(self, area: str, older_than_s: float) -> int:
        return self.published.prune(area, older_than_s)

    # --- removal: the one collector, through the trash -----------------------------------

    def discard(self, files: Iterable[StoredFile], in_use: Collection[str] = ()) -> int:
        return discard_created(files, in_use, self.trash.remove_if)

    def collect(self, paths: Iterable[str], in_use: Collection[str]) -> list[str]:
        return collect_unclaimed(paths, in_use, self.grace_s, self.trash.remove_if)

    def sweep_orphans(
        self, areas: Iterable[str], known: set[str], older_than_s: float | None = None
    ) -> list[str]:
        """The bucket's sweep (``Trash.sweep``), then this machine's stale temporaries."""
        grace = self.grace_s if older_than_s is None else older_than_s
        removed = self.trash.sweep(areas, known, self.grace_s, grace)
        self.files.sweep_temporaries()
        return removed


@lru_cache(maxsize=16)
def _store(
    home: Path,
    url: str,
    grace_s: float,
    endpoint_url: str | None,
    cache_bytes: int,
    waits: StoreWaits,
) -> ObjectStorage:
    """One store per process, configuration and waits (a request's, a job's)."""
    return ObjectStorage(home, url, grace_s, endpoint_url, cache_bytes, waits=waits)
