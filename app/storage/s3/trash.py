"""The object store's one collector, through the trash.

S3 has no atomic rename, so the collector moves an object to ``trash/<relative>`` (a copy, then a
delete) when nobody claimed it within the grace period. A claim can land between its look and
its delete; the row committed then names a trashed object, so a reader that misses the key puts
the trashed copy back (``restore``), and every sweep restores the trashed objects a committed
row names before it purges the others a grace period after they were trashed.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import structlog

from app.storage.protocol import Unclaimed
from app.storage.s3.bucket import Bucket
from app.storage.s3.cache import ObjectCache

log = structlog.get_logger(__name__)
TRASH = "trash"


class Trash:
    """Removal from a bucket (and its cached copies), never from under a claim."""

    def __init__(self, bucket: Bucket, cache: ObjectCache) -> None:
        self.bucket = bucket
        self.cache = cache

    def remove_if(self, relative: str, unclaimed: Unclaimed) -> bool:
        """Move an object to the trash when its claim time says nobody claimed it (and drop
        the cached copy); a claim made meanwhile is covered by the trash's restore."""
        try:
            self.cache.files.local(relative)
        except ValueError:  # a row naming a path outside the store: never touched
            return False
        claimed = self.bucket.claim_ns(relative)
        if claimed is None or not unclaimed(claimed):
            return False
        if not self.bucket.copy(relative, f"{TRASH}/{relative}"):
            return False  # another collector (or deletion) took it meanwhile
        self.bucket.delete(relative)
        self.cache.drop(relative)
        return True

    def restore(self, relative: str) -> bool:
        """Put a trashed object back under its key; False when the trash has none."""
        return self.bucket.stamped_copy(f"{TRASH}/{relative}", relative)

    def lost(self, paths: Iterable[str]) -> set[str]:
        """Those of ``paths`` (files or folders) the bucket holds neither under their key nor
        in the trash (a reader restores a trashed one); one listing per area, no download."""
        wanted = set(paths)
        held: set[str] = set()
        for area in {p.split("/", 1)[0] for p in wanted}:
            for prefix in (f"{area}/", f"{TRASH}/{area}/"):
                held.update(
                    self.bucket.relative_of(o["Key"]).removeprefix(f"{TRASH}/")
                    for o in self.bucket.objects(prefix)
                )
        folders = {p.rsplit("/", i)[0] for p in held for i in range(1, p.count("/") + 1)}
        return wanted - held - folders

    def sweep(
        self, areas: Iterable[str], known: set[str], grace_s: float, older_than_s: float
    ) -> list[str]:
        """Trashed objects a committed row names (``known``) go back, the others are purged
        ``grace_s`` after they were trashed; then objects of ``areas`` no row names and nobody
        claimed for ``older_than_s`` are trashed. Returns those trashed."""
        self._empty(known, grace_s)
        from botocore.exceptions import BotoCoreError, ClientError

        cutoff_ns = int((time.time() - older_than_s) * 1e9)
        removed = []
        for area in areas:
            for item in self.bucket.objects(f"{area}/"):
                relative = self.bucket.relative_of(item["Key"])
                if relative in known:  # the others are few: each is looked at (HEAD)
                    continue
                try:
                    if self.remove_if(relative, lambda ns: ns < cutoff_ns):
                        removed.append(relative)
                except (BotoCoreError, ClientError) as exc:
                    log.warning("storage.sweep_failed", path=relative, error=str(exc))
        return removed

    def _empty(self, known: set[str], grace_s: float) -> None:
        """Restore the trashed objects ``known`` names; purge the others trashed ``grace_s``
        ago."""
        from botocore.exceptions import BotoCoreError, ClientError

        purge_before = time.time() - grace_s
        purged = []
        for item in self.bucket.objects(f"{TRASH}/"):
            relative = self.bucket.relative_of(item["Key"]).removeprefix(f"{TRASH}/")
            try:
                if relative in known:
                    self.restore(relative)
                elif item["LastModified"].timestamp() >= purge_before:
                    continue
            except (BotoCoreError, ClientError) as exc:  # this object waits for the next sweep
                log.warning("storage.sweep_failed", path=relative, error=str(exc))
                continue
            purged.append(item["Key"])
        self.bucket.delete_keys(purged)
