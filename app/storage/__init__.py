"""The storage seam: one ``Storage`` protocol (``protocol``), two backends: content-addressed
files under WELDPOOL_HOME (``LocalStorage``), or an S3-compatible object store composed over home
as its bounded read cache (``ObjectStorage``). ``open_storage(settings)`` picks one from
WELDPOOL_STORAGE_URL; it is the one place that does."""

from __future__ import annotations

from typing import TYPE_CHECKING

from app.storage.local import LocalStorage
from app.storage.protocol import (
    CHUNK,
    DEFAULT_GRACE_S,
    EXPORTS_DIR,
    SHARED_AREAS,
    StagedFile,
    Storage,
    StoredFile,
)
from app.storage.s3 import ObjectStorage
from app.storage.writes import best_effort

if TYPE_CHECKING:
    from app.core.config import Settings


def open_storage(settings: Settings, *, for_requests: bool = False) -> Storage:
    """The store of an instance (WELDPOOL_STORAGE_URL), with its grace period; a remote
    store's calls wait as a job's may (WELDPOOL_STORAGE_JOB_*), or ``for_requests`` the
    short bounds a person waits on (WELDPOOL_STORAGE_REQUEST_*, also the checks')."""
    if settings.storage_url:  # s3://… (the settings allow no other scheme)
        return ObjectStorage.for_settings(settings, settings.storage_waits(jobs=not for_requests))
    return LocalStorage(settings.home, settings.file_grace_s)


__all__ = [
    "CHUNK",
    "DEFAULT_GRACE_S",
    "EXPORTS_DIR",
    "SHARED_AREAS",
    "LocalStorage",
    "ObjectStorage",
    "StagedFile",
    "Storage",
    "StoredFile",
    "best_effort",
    "open_storage",
]
