"""The storage seam: content-addressed files under WELDPOOL_HOME (``local``), or in an
S3-compatible object store with the home folder as a bounded read cache (``s3``), chosen by
WELDPOOL_STORAGE_URL. Callers see one ``Storage``; ``Storage.of(settings)`` picks the backend."""

from app.storage.local import (
    CHUNK,
    DEFAULT_GRACE_S,
    EXPORTS_DIR,
    SHARED_AREAS,
    StagedFile,
    Storage,
    StoredFile,
    best_effort,
)
from app.storage.s3 import ObjectStorage  # registers the s3:// backend (boto3 loads on first use)

__all__ = [
    "CHUNK",
    "DEFAULT_GRACE_S",
    "EXPORTS_DIR",
    "SHARED_AREAS",
    "ObjectStorage",
    "StagedFile",
    "Storage",
    "StoredFile",
    "best_effort",
]
