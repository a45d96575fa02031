"""Shared files in an S3-compatible object store (AWS S3, MinIO, Ceph), with home as this
machine's bounded read cache: ``WELDPOOL_STORAGE_URL=s3://bucket/prefix``.

Every object's key is ``<prefix>/<relative path>``, the same relative path the database
holds, so a row means the same file on every machine. The promises of ``app.storage.local``
hold on this backend too:

- **Written whole before its row is committed.** ``stage``/``put``/``put_stream`` upload before
  they return (one PUT, or a multipart upload that S3 makes visible only once complete), in the
  caller's threads: the ingest's disk threads upload while the rest of the request is checked.
- **Content-addressed and claimed.** A claim is a copy of the object onto itself that sets its
  ``claimed`` metadata (and so its LastModified) to now; a missing key means not stored.
- **Removed only by the collector, never from under a claim.** The collector moves an object
  to ``trash/<relative>`` (a copy, then a delete) when nobody claimed it within the grace
  period. A claim can land between its look and its delete (S3 has no atomic rename); the row
  committed then names a trashed object, so a reader that misses the key puts the trashed copy
  back, and every sweep restores the trashed objects that a committed row names before it
  purges the others a grace period after they were trashed.
- **A bounded local cache.** Files written or fetched land under home at their relative path
  and are read from there; past WELDPOOL_STORAGE_CACHE_MB the least recently used go (they
  are in the bucket). Reads and writes stream through files: no whole video or export in memory.

The client is boto3 (``bench/storage.py`` measures it beside obstore): the AWS SDK itself,
thread-safe, with managed multipart transfers and the standard credential chain.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Executor
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

import structlog

from app.core.budgets import shared_pool
from app.core.errors import without_addresses
from app.storage.local import (
    CHUNK,
    PART_LIFETIME_S,
    REMOTE_BACKENDS,
    SHARED_AREAS,
    StagedFile,
    Storage,
    StoredFile,
)

if TYPE_CHECKING:
    from app.core.config import Settings, StoreWaits

log = structlog.get_logger(__name__)
CONTENT_AREAS = ("frames", "videos", "artefacts")
"""Content-addressed areas: read through the cache by ``absolute`` and bounded by it."""
TRASH = "trash"
MARKER = "cache/storage-url"
"""In a home that is a store's cache: the store's URL (``check`` refuses a home holding files of
its own, which the cache would evict before any other machine saw them)."""
MULTIPART_BYTES = 64 * 1024 * 1024
"""Uploads and downloads above this go in parts (videos, exports); frames in one request."""
TOUCH_EVERY_S = 60.0
"""A cached file read again is marked recent at most once a minute (the cache's LRU order)."""
IN_USE_S = 600.0
"""The cache never evicts a file written, fetched or read within this long: a request or job
that was just handed its path is still reading it (the bound may be passed meanwhile)."""
_PUBLISH_POOL = shared_pool(8, "storage-publish")  # publishing, and reading ahead


def parse_url(url: str) -> tuple[str, str]:
    """``s3://bucket/prefix`` → (bucket, prefix without slashes); a clear error otherwise."""
    parsed = urlparse(url)
    if parsed.scheme != "s3" or not parsed.netloc:
        raise ValueError(
            f"WELDPOOL_STORAGE_URL must be empty (the home folder) or s3://bucket/prefix, "
            f"not {url!r}"
        )
    return parsed.netloc, parsed.path.strip("/")


@lru_cache(maxsize=16)
def _client(endpoint_url: str | None, region: str | None, waits: StoreWaits) -> Any:
    """One boto3 client per endpoint, waits and process (making one costs ~50 ms; it is
    thread-safe)."""
    import boto3
    from botocore.config import Config

    config = Config(
        max_pool_connections=16,
        retries={"mode": "standard", "total_max_attempts": waits.attempts},
        connect_timeout=waits.connect_s,
        read_timeout=waits.read_s,
    )
    return boto3.client(
        "s3", endpoint_url=endpoint_url or None, region_name=region or None, config=config
    )


def _missing(error: Exception) -> bool:
    """Whether a botocore error says the key (or bucket) is not there."""
    response = getattr(error, "response", None) or {}
    code = str(response.get("Error", {}).get("Code", ""))
    status = response.get("ResponseMetadata", {}).get("HTTPStatusCode")
    return code in {"NoSuchKey", "404", "NotFound"} or status == 404


class ObjectStorage(Storage):
    """``Storage`` whose shared files live in a bucket; home caches them."""

    _flush_local = False  # the bucket holds the durable copy; home's files are a cache

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
        super().__init__(home, grace_s)
        self.remote = url
        self.bucket, self.prefix = parse_url(url)
        self.waits = waits
        self.client = _client(endpoint_url, region or os.environ.get("AWS_REGION"), waits)
        self.cache_bytes = cache_bytes
        self.reads = 0
        """Objects read from the bucket by this store (``bench/storage.py`` counts a click's)."""
        self._since_trim = 0
        self._lock = threading.Lock()
        self._is_cache()  # marks a fresh home as this store's cache

    @classmethod
    def for_settings(cls, settings: Settings, waits: StoreWaits) -> ObjectStorage:
        assert settings.storage_url
        return _store(
            settings.home.resolve(),
            settings.storage_url,
            settings.file_grace_s,
            settings.s3_endpoint_url,
            int(settings.storage_cache_mb * 1024 * 1024),
            waits,
        )

    def key(self, relative: str) -> str:
        return f"{self.prefix}/{relative}" if self.prefix else relative

    def relative_of(self, key: str) -> str:
        return key.removeprefix(f"{self.prefix}/") if self.prefix else key

    def problem(self, *, named: bool = False) -> str | None:
        """Why the bucket cannot be used, in one sentence (one HEAD, waiting at most
        ``waits.longest_s``), or None; ``named``: the sentence names the store's URL (not for
        /health, which anyone may read)."""
        try:
            self.client.head_bucket(Bucket=self.bucket)
        except Exception as exc:
            store = f"The object store {self.remote}" if named else "The object store"
            if _missing(exc):
                return (
                    f"{store} cannot be used: its bucket does not exist; create it with "
                    "`weldpool storage create-bucket`."
                )
            return (
                f"{store} cannot be used ({_reason(exc, self.waits)}); check "
                "WELDPOOL_STORAGE_URL, WELDPOOL_S3_ENDPOINT_URL and the AWS_* credentials."
            )
        return None

    def check(self) -> None:
        """Raise a clear error when the bucket cannot be reached (at start-up), or home holds
        files of its own."""
        from app.core.errors import ConfigurationError

        problem = self.problem(named=True)
        if problem:
            raise ConfigurationError(problem)
        if not self._is_cache():
            own = next((a for a in SHARED_AREAS if any(_files(self.home / a))), "files")
            raise ConfigurationError(
                f"WELDPOOL_HOME ({self.home}) holds {own} of its own that {self.remote} may "
                "lack; upload them first with `weldpool storage push`, or give this machine an "
                "empty home."
            )

    def _is_cache(self) -> bool:
        """Whether home is this store's cache: marked so, or marked now when it holds no
        shared files of its own (a fresh home)."""
        marker = self.home / MARKER
        with contextlib.suppress(FileNotFoundError):
            return marker.read_text().strip() == self.remote
        if any(any(_files(self.home / area)) for area in SHARED_AREAS):
            return False
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text(f"{self.remote}\n")
        return True

    def push(self) -> tuple[int, int]:
        """Upload every shared file of home the bucket lacks (an instance that kept its files
        in home, moving to the store); returns (uploaded, already there). Home is then this
        store's cache."""
        present = {self.relative_of(o["Key"]) for a in SHARED_AREAS for o in self._objects(f"{a}/")}
        local = [
            p.relative_to(self.home).as_posix() for a in SHARED_AREAS for p in _files(self.home / a)
        ]
        missing = [r for r in local if r not in present and not r.startswith("models/.work")]
        now = time.time_ns()
        list(_PUBLISH_POOL.map(lambda r: self._upload_file(self.home / r, r, now), missing))
        (self.home / MARKER).parent.mkdir(parents=True, exist_ok=True)
        (self.home / MARKER).write_text(f"{self.remote}\n")
        return len(missing), len(local) - len(missing)

    # --- claims and writes --------------------------------------------------------------

    def _claimed(self, relative: str) -> bool:
        """Claim an object: copy it onto itself with ``claimed`` = now (LastModified moves)."""
        return self._stamped_copy(relative, relative)

    def _stamped_copy(self, source: str, target: str) -> bool:
        """Copy ``source`` to ``target`` (both relative) with ``claimed`` = now; False when
        ``source`` is not there."""
        from botocore.exceptions import ClientError

        try:
            self.client.copy_object(
                Bucket=self.bucket,
                Key=self.key(target),
                CopySource={"Bucket": self.bucket, "Key": self.key(source)},
                MetadataDirective="REPLACE",
                Metadata={"claimed": str(time.time_ns())},
            )
        except ClientError as exc:
            if _missing(exc):
                return False
            raise
        return True

    def _upload_file(self, path: Path, relative: str, claimed_ns: int) -> None:
        from boto3.s3.transfer import TransferConfig

        self.client.upload_file(
            str(path),
            self.bucket,
            self.key(relative),
            ExtraArgs={"Metadata": {"claimed": str(claimed_ns)}},
            Config=TransferConfig(multipart_threshold=MULTIPART_BYTES, max_concurrency=4),
        )

    def _cache_place(self, temporary: Path, relative: str) -> None:
        """Keep a written temporary as the cached copy of ``relative``."""
        final = self.home / relative
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(temporary, final)
        self._count(final.stat().st_size)

    def _install(self, temporary: Path, relative: str) -> StoredFile:
        """Upload a written temporary unless the same content is stored (then claim it); the
        temporary becomes the cached copy either way."""
        try:
            if self._claimed(relative):
                self._cache_place(temporary, relative)
                return StoredFile(relative, created=False)
            claimed = time.time_ns()
            self._upload_file(temporary, relative, claimed)
            self._cache_place(temporary, relative)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        return StoredFile(relative, created=True, claimed_ns=claimed)

    def put(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StoredFile:
        relative = self.relative_path(area, sha256, extension)
        claimed = self._create_or_claim(data, relative)
        if claimed is None:
            return StoredFile(relative, created=False)
        self._cache_place(self._write_temporary(data), relative)
        return StoredFile(relative, created=True, claimed_ns=claimed)

    def _create_or_claim(self, data: bytes, relative: str) -> int | None:
        """Upload content unless its key exists (one conditional PUT, ``If-None-Match: *``);
        returns the new object's claim time, or None when the stored one was claimed."""
        from botocore.exceptions import ClientError

        for _ in range(8):  # another writer's object can appear (or go) between two requests
            claimed = time.time_ns()
            try:
                self.client.put_object(
                    Bucket=self.bucket,
                    Key=self.key(relative),
                    Body=data,
                    Metadata={"claimed": str(claimed)},
                    IfNoneMatch="*",
                )
                return claimed
            except ClientError as exc:
                code = str(exc.response.get("Error", {}).get("Code", ""))
                if code not in {"PreconditionFailed", "ConditionalRequestConflict", "412"}:
                    raise
            if self._claimed(relative):
                return None
        raise OSError(f"{relative} could neither be claimed nor written; check the store.")

    def stage(self, data: bytes, sha256: str, extension: str, area: str = "frames") -> StagedFile:
        """Upload new content now (in the caller's thread) and keep a cache copy aside;
        ``install_many`` only puts the copy in place, ``unstage`` withdraws the upload."""
        relative = self.relative_path(area, sha256, extension)
        claimed = self._create_or_claim(data, relative)
        if claimed is None:
            return StagedFile(relative, None)
        return StagedFile(relative, self._write_temporary(data), uploaded_ns=claimed)

    def unstage(self, staged: Iterable[StagedFile]) -> None:
        items = list(staged)
        super().unstage(items)
        self.discard(
            StoredFile(s.relative, created=True, claimed_ns=s.uploaded_ns)
            for s in items
            if s.uploaded_ns
        )

    def install_many(
        self, staged: Sequence[StagedFile], executor: Executor | None = None
    ) -> list[StoredFile]:
        results: list[StoredFile] = []
        try:
            for item in staged:
                if item.temporary is None:
                    results.append(StoredFile(item.relative, created=False))
                elif item.uploaded_ns and time.time_ns() - item.uploaded_ns < self.grace_s * 5e8:
                    self._cache_place(item.temporary, item.relative)
                    results.append(StoredFile(item.relative, True, item.uploaded_ns))
                elif item.uploaded_ns:  # uploaded more than half a grace period ago: claim anew
                    results.append(self._install(item.temporary, item.relative))
                else:
                    results.append(self._install(item.temporary, item.relative))
        except BaseException:
            self.discard(results)
            self.unstage(staged[len(results) :])
            raise
        return results

    # --- reads through the cache ---------------------------------------------------------

    def absolute(self, relative: str) -> Path:
        """The cached copy of a stored file, fetched from the bucket when this machine has
        none (content areas; other paths are this machine's own)."""
        path = super().absolute(relative)
        if relative.split("/", 1)[0] in CONTENT_AREAS:
            self._ensure(relative, path)
        return path

    def fetch(self, relative: str) -> Path:
        path = super().absolute(relative)
        if relative.split("/", 1)[0] in SHARED_AREAS:
            self._ensure(relative, path)
        return path

    def fetch_ahead(self, paths: Iterable[str]) -> None:
        for relative in paths:
            _PUBLISH_POOL.submit(self._fetched_ahead, relative)

    def _fetched_ahead(self, relative: str) -> None:
        """A file read ahead: whatever goes wrong is met again by the read that wants it."""
        with contextlib.suppress(Exception):
            self.fetch(relative)

    def _ensure(self, relative: str, path: Path) -> None:
        try:
            changed = path.stat().st_mtime
        except FileNotFoundError:
            self._download(relative, path)
            return
        if time.time() - changed > TOUCH_EVERY_S:
            with contextlib.suppress(FileNotFoundError):
                os.utime(path)

    def _download(self, relative: str, path: Path, restore: bool = True) -> bool:
        """Stream an object into the cache (one GET); a key found only in the trash is put
        back first. False when neither holds it (the caller then sees no file)."""
        from botocore.exceptions import ClientError

        key = self.key(relative)
        try:
            response = self.client.get_object(Bucket=self.bucket, Key=key)
        except ClientError as exc:
            if not (_missing(exc) and restore and self._restore(relative)):
                if _missing(exc):
                    return False
                raise
            return self._download(relative, path, restore=False)
        self.reads += 1
        temporary = self._temporary()
        try:
            with response["Body"] as body, open(temporary, "wb") as handle:
                shutil.copyfileobj(body, handle, CHUNK)
            path.parent.mkdir(parents=True, exist_ok=True)
            os.replace(temporary, path)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        self._count(path.stat().st_size)
        return True

    def holds(self, relative: str) -> bool:
        """Whether the bucket holds the object ``relative`` (one HEAD; this machine's cached
        copy does not count: other machines cannot read it)."""
        return self._claim_ns(relative) is not None

    def lost(self, paths: Iterable[str]) -> set[str]:
        """Those of ``paths`` (files or folders) the bucket holds neither under their key nor
        in the trash (a reader restores a trashed one); one listing per area, no download. A
        copy in this machine's cache does not count: other machines cannot read it."""
        wanted = set(paths)
        held: set[str] = set()
        for area in {p.split("/", 1)[0] for p in wanted}:
            for prefix in (f"{area}/", f"{TRASH}/{area}/"):
                held.update(
                    self.relative_of(o["Key"]).removeprefix(f"{TRASH}/")
                    for o in self._objects(prefix)
                )
        folders = {p.rsplit("/", i)[0] for p in held for i in range(1, p.count("/") + 1)}
        return wanted - held - folders

    def _restore(self, relative: str) -> bool:
        """Put a trashed object back under its key; False when the trash has none."""
        return self._stamped_copy(f"{TRASH}/{relative}", relative)

    def _count(self, size: int) -> None:
        with self._lock:
            self._since_trim += size
            due = self._since_trim > self.cache_bytes // 10
            if due:
                self._since_trim = 0
        if due:
            self.trim_cache()

    def trim_cache(self) -> int:
        """Remove the least recently used cached content files until the cache holds at
        most 80 % of its bound, never one used within ``IN_USE_S``; returns the bytes freed."""
        files = []
        for area in CONTENT_AREAS:
            root = self.home / area
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

    # --- shared files that are not content-addressed -----------------------------------

    def _objects(self, relative: str) -> Iterator[dict[str, Any]]:
        """The bucket's objects under ``relative`` (a prefix), with their keys and sizes."""
        paginator = self.client.get_paginator("list_objects_v2")
        for page in paginator.paginate(Bucket=self.bucket, Prefix=self.key(relative)):
            yield from page.get("Contents", [])

    def folder(self, relative: str) -> Path | None:
        """A published folder, made complete on this machine: files it lacks, or holds older
        than the bucket's (a job replaced them), are fetched. Files only this machine has stay
        (an ONNX export a live view made from the weights)."""
        path = super().absolute(relative)
        objects = {self.relative_of(o["Key"]): o for o in self._objects(f"{relative}/")}
        if not objects:
            return path if path.is_dir() else None
        for name, item in objects.items():
            local = self.home / name
            stamp = item["LastModified"].timestamp()
            try:
                info = local.stat()
                current = info.st_size == item["Size"] and info.st_mtime >= stamp
            except FileNotFoundError:
                current = False
            if not current and self._download(name, local, restore=False):
                os.utime(local, (stamp, stamp))
        return path

    def has_folder(self, relative: str) -> bool:
        response = self.client.list_objects_v2(
            Bucket=self.bucket, Prefix=self.key(f"{relative}/"), MaxKeys=1
        )
        return bool(response.get("KeyCount")) or super().has_folder(relative)

    def publish(self, relative: str, names: Iterable[str] | None = None) -> None:
        """Upload a file, or a folder's files, under their relative paths; returns once every
        upload is complete. A folder is made to match this machine's copy (keys it lacks are
        withdrawn) — unless ``names`` are given: then only those files of it are uploaded, or
        withdrawn where this copy has none (another job may be changing the folder's others).
        Each uploaded file's modification time becomes its object's, so ``folder`` knows it
        current."""
        path = super().absolute(relative)
        now = time.time_ns()
        if path.is_file():
            self._upload_file(path, relative, now)
            return
        if not path.is_dir():
            raise FileNotFoundError(f"{relative} is not on this machine; nothing to publish.")
        if names is None:
            files = {p.relative_to(self.home).as_posix(): p for p in path.rglob("*") if p.is_file()}
            gone = [
                o["Key"]
                for o in self._objects(f"{relative}/")
                if self.relative_of(o["Key"]) not in files
            ]
        else:
            chosen = {f"{relative}/{name}": path / name for name in names}
            files = {key: local for key, local in chosen.items() if local.is_file()}
            gone = [self.key(key) for key in chosen if key not in files]
        list(_PUBLISH_POOL.map(lambda i: self._upload_file(i[1], i[0], now), files.items()))
        self._delete_keys(gone)
        for item in self._objects(f"{relative}/"):  # local times := the bucket's
            local = files.get(self.relative_of(item["Key"]))
            if local is not None:
                stamp = item["LastModified"].timestamp()
                with contextlib.suppress(FileNotFoundError):
                    os.utime(local, (stamp, stamp))

    def unpublish(self, relative: str) -> None:
        keys = [o["Key"] for o in self._objects(f"{relative}/")]
        self._delete_keys([*keys, self.key(relative)])

    def _delete_keys(self, keys: Iterable[str]) -> None:
        batch = list(keys)
        for start in range(0, len(batch), 1000):  # S3's limit per request
            chunk = batch[start : start + 1000]
            if chunk:
                self.client.delete_objects(
                    Bucket=self.bucket,
                    Delete={"Objects": [{"Key": k} for k in chunk], "Quiet": True},
                )

    def share(self, relative: str, path: Path) -> None:
        self._upload_file(path, relative, time.time_ns())

    def pull(self, relative: str, path: Path) -> bool:
        return self._download(relative, path, restore=False)

    def prune_published(self, area: str, older_than_s: float) -> int:
        cutoff = time.time() - older_than_s
        old = [
            o["Key"] for o in self._objects(f"{area}/") if o["LastModified"].timestamp() < cutoff
        ]
        self._delete_keys(old)
        return len(old)

    # --- removal: the one collector, through the trash -----------------------------------

    def _claim_ns(self, relative: str) -> int | None:
        """An object's claim time (its ``claimed`` metadata, else LastModified); None when
        it is not there."""
        from botocore.exceptions import ClientError

        try:
            head = self.client.head_object(Bucket=self.bucket, Key=self.key(relative))
        except ClientError as exc:
            if _missing(exc):
                return None
            raise
        claimed = head.get("Metadata", {}).get("claimed")
        if claimed and claimed.isdigit():
            return int(claimed)
        return int(head["LastModified"].timestamp() * 1e9)

    def _remove_if(self, relative: str, unclaimed: Any) -> bool:
        """Move an object to the trash when its claim time says nobody claimed it (and drop
        the cached copy); a claim made meanwhile is covered by the trash's restore."""
        try:
            super().absolute(relative)
        except ValueError:  # a row naming a path outside the store: never touched
            return False
        claimed = self._claim_ns(relative)
        if claimed is None or not unclaimed(claimed):
            return False
        from botocore.exceptions import ClientError

        key = self.key(relative)
        try:
            self.client.copy_object(
                Bucket=self.bucket,
                Key=self.key(f"{TRASH}/{relative}"),
                CopySource={"Bucket": self.bucket, "Key": key},
            )
        except ClientError as exc:
            if _missing(exc):  # another collector (or deletion) took it meanwhile
                return False
            raise
        self.client.delete_object(Bucket=self.bucket, Key=key)
        (self.home / relative).unlink(missing_ok=True)
        return True

    def sweep_orphans(
        self, areas: Iterable[str], known: set[str], older_than_s: float | None = None
    ) -> list[str]:
        """The bucket's sweep: trashed objects a committed row names go back, the others are
        purged a grace period after they were trashed; then objects of ``areas`` no row names
        and nobody claimed for ``older_than_s`` (the grace period by default) are trashed.
        ``known`` must be read before the sweep starts."""
        from botocore.exceptions import BotoCoreError, ClientError

        grace = self.grace_s if older_than_s is None else older_than_s
        purge_before = time.time() - self.grace_s
        purged = []
        for item in self._objects(f"{TRASH}/"):
            relative = self.relative_of(item["Key"]).removeprefix(f"{TRASH}/")
            try:
                if relative in known:
                    self._restore(relative)
                elif item["LastModified"].timestamp() >= purge_before:
                    continue
            except (BotoCoreError, ClientError) as exc:  # this object waits for the next sweep
                log.warning("storage.sweep_failed", path=relative, error=str(exc))
                continue
            purged.append(item["Key"])
        self._delete_keys(purged)
        cutoff_ns = int((time.time() - grace) * 1e9)
        removed = []
        for area in areas:
            for item in self._objects(f"{area}/"):
                relative = self.relative_of(item["Key"])
                if relative in known:  # the others are few: each is looked at (HEAD)
                    continue
                try:
                    if self._remove_if(relative, lambda ns: ns < cutoff_ns):
                        removed.append(relative)
                except (BotoCoreError, ClientError) as exc:
                    log.warning("storage.sweep_failed", path=relative, error=str(exc))
        parts_cutoff = time.time() - max(PART_LIFETIME_S, self.grace_s)
        for stale in self.tmp.glob("*.part") if self.tmp.is_dir() else ():
            try:
                if stale.stat().st_mtime < parts_cutoff:
                    stale.unlink(missing_ok=True)
            except FileNotFoundError:
                continue
        return removed


REMOTE_BACKENDS["s3"] = ObjectStorage.for_settings


@lru_cache(maxsize=16)
def _store(
    home: Path,
    url: str,
    grace_s: float,
    endpoint_url: str | None,
    cache_bytes: int,
    waits: StoreWaits,
) -> ObjectStorage:
    """One store per process, configuration and waits (a request's, a job's), so its cache
    accounting is shared."""
    return ObjectStorage(home, url, grace_s, endpoint_url, cache_bytes, waits=waits)


def _files(root: Path) -> Iterator[Path]:
    """The files under ``root`` (none when it is absent)."""
    return (p for p in root.rglob("*") if p.is_file()) if root.is_dir() else iter(())


def _reason(exc: Exception, waits: StoreWaits) -> str:
    """What the store answered, in words without its address (botocore's own messages name
    the endpoint's URL)."""
    from botocore.exceptions import ConnectionError as NoConnection
    from botocore.exceptions import ConnectTimeoutError, ReadTimeoutError

    response = getattr(exc, "response", None)
    if response:
        error = response.get("Error", {})
        return f"{error.get('Code', '')} {error.get('Message', '')}".strip() or type(exc).__name__
    if isinstance(exc, ConnectTimeoutError | ReadTimeoutError):
        return f"it did not answer within {waits.longest_s:g} s"
    if isinstance(exc, NoConnection):
        return "nothing answers at its address"
    return without_addresses(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)


def download_prefix(url: str, folder: Path, endpoint_url: str | None, *, waits: StoreWaits) -> Path:
    """Copy ``s3://bucket/key`` (one object) or ``s3://bucket/prefix`` (every object under it,
    its folders kept) into ``folder``, streamed to disk; returns the local file or folder
    (named like the key's last part). For ``weldpool import`` and ``import-labels`` from a
    bucket a camera rig or another tool fills, with the store's endpoint and credentials."""
    import posixpath

    from botocore.exceptions import BotoCoreError, ClientError

    from app.core.errors import InvalidInputError

    bucket, key = parse_url(url)
    client = _client(endpoint_url, os.environ.get("AWS_REGION"), waits)
    target = folder / (posixpath.basename(key) or bucket)
    try:
        listed = [
            item["Key"]
            for page in client.get_paginator("list_objects_v2").paginate(
                Bucket=bucket, Prefix=f"{key}/" if key else ""
            )
            for item in page.get("Contents", [])
            if not item["Key"].endswith("/")
        ]
        if not listed and key:  # one object
            _get_to(client, bucket, key, target)
            return target
        if not listed:
            raise InvalidInputError(f"{url} holds no objects.")
        for name in listed:
            relative = posixpath.normpath(name.removeprefix(f"{key}/" if key else ""))
            if relative.startswith(("../", "/")) or relative == "..":
                continue  # a key that would land outside the folder
            _get_to(client, bucket, name, target / relative)
    except ClientError as exc:
        if _missing(exc):
            raise InvalidInputError(f"{url} does not exist.") from None
        raise InvalidInputError(f"{url} cannot be read ({_reason(exc, waits)}).") from None
    except BotoCoreError as exc:
        raise InvalidInputError(f"{url} cannot be read ({_reason(exc, waits)}).") from None
    return target


def _get_to(client: Any, bucket: str, key: str, path: Path) -> None:
    """Stream one object to ``path``."""
    response = client.get_object(Bucket=bucket, Key=key)
    path.parent.mkdir(parents=True, exist_ok=True)
    with response["Body"] as body, open(path, "wb") as handle:
        shutil.copyfileobj(body, handle, CHUNK)
