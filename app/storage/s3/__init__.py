"""The object store backend (``WELDPOOL_STORAGE_URL=s3://bucket/prefix``), by job: the bucket's
keys, claims and transfers (``bucket``; ingest's PUT through obstore, ``uploads``), home as its
bounded cache (``cache``), the collector through the trash (``trash``), folders published by
name (``published``), and ``ObjectStorage`` composing them (``store``). boto3 and obstore load
on first use."""

from app.storage.s3.bucket import MULTIPART_BYTES, download_prefix, parse_url
from app.storage.s3.cache import IN_USE_S
from app.storage.s3.store import ObjectStorage
from app.storage.s3.trash import TRASH

__all__ = ["IN_USE_S", "MULTIPART_BYTES", "TRASH", "ObjectStorage", "download_prefix", "parse_url"]
