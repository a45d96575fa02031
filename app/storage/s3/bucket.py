"""One bucket under a prefix, as the object store uses it: keys, claims, transfers and listings.

Every object's key is ``<prefix>/<relative path>``, the same relative path the database holds,
so a row means the same file on every machine. A claim is the object's ``claimed`` metadata (a
copy of the object onto itself sets it to now, and so its LastModified).

Two clients, one bucket: boto3 (the AWS SDK: claims, reads, listings, deletions, multipart
uploads of files, and the standard credential chain) and, for the one request ingest makes per
frame (the conditional PUT of bytes held in memory), obstore, set up as boto3's client is and
raising botocore's errors (``uploads.py``).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterable, Iterator
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO
from urllib.parse import urlparse

from app.core.errors import without_addresses
from app.storage.protocol import CHUNK
from app.storage.s3 import uploads

if TYPE_CHECKING:
    from app.core.config import StoreWaits

MULTIPART_BYTES = 64 * 1024 * 1024
"""Uploads and downloads above this go in parts (videos, exports); frames in one request."""


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
def client_for(endpoint_url: str | None, region: str | None, waits: StoreWaits) -> Any:
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


def missing(error: Exception) -> bool:
    """Whether a botocore error says the key (or bucket) is not there."""
    response = getattr(error, "response", None) or {}
    code = str(response.get("Error", {}).get("Code", ""))
    status = response.get("ResponseMetadata", {}).get("HTTPStatusCode")
    return code in {"NoSuchKey", "404", "NotFound"} or status == 404


def reason(exc: Exception, waits: StoreWaits) -> str:
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


class Bucket:
    """The objects of one ``s3://bucket/prefix``, named by their relative paths."""

    def __init__(
        self, url: str, endpoint_url: str | None, region: str | None, waits: StoreWaits
    ) -> None:
        self.name, self.prefix = parse_url(url)
        self.client = client_for(endpoint_url, region, waits)
        self.waits = waits

    def key(self, relative: str) -> str:
        return f"{self.prefix}/{relative}" if self.prefix else relative

    def relative_of(self, key: str) -> str:
        return key.removeprefix(f"{self.prefix}/") if self.prefix else key

    def problem(self, store: str) -> str | None:
        """Why the bucket cannot be used, in one sentence about ``store`` (one HEAD, waiting
        at most ``waits.longest_s``), or None."""
        try:
            self.client.head_bucket(Bucket=self.name)
        except Exception as exc:
            if missing(exc):
                return (
                    f"{store} cannot be used: its bucket does not exist; create it with "
                    "`weldpool storage create-bucket`."
                )
            return (
                f"{store} cannot be used ({reason(exc, self.waits)}); check "
                "WELDPOOL_STORAGE_URL, WELDPOOL_S3_ENDPOINT_URL and the AWS_* credentials."
            )
        return None

    # --- writes and claims --------------------------------------------------------------

    def create(self, data: bytes, relative: str) -> int | None:
        """Upload content unless its key exists (one conditional PUT, ``If-None-Match: *``,
        through obstore: ``uploads.py``); returns the new object's claim time, or None when an
        object is there already."""
        claimed = time.time_ns()
        if not uploads.create(
            self.client, self.name, self.key(relative), data, claimed, self.waits
        ):
            return None
        return claimed

    def upload_file(self, path: Path, relative: str, claimed_ns: int) -> None:
        """Upload a file (in parts past ``MULTIPART_BYTES``, visible only once complete)."""
        from boto3.s3.transfer import TransferConfig

        self.client.upload_file(
            str(path),
            self.name,
            self.key(relative),
            ExtraArgs={"Metadata": {"claimed": str(claimed_ns)}},
            Config=TransferConfig(multipart_threshold=MULTIPART_BYTES, max_concurrency=4),
        )

    def stamped_copy(self, source: str, target: str) -> bool:
        """Copy ``source`` to ``target`` (both relative) with ``claimed`` = now; False when
        ``source`` is not there. Onto itself, this is a claim."""
        from botocore.exceptions import ClientError

        try:
            self.client.copy_object(
                Bucket=self.name,
                Key=self.key(target),
                CopySource={"Bucket": self.name, "Key": self.key(source)},
                MetadataDirective="REPLACE",
                Metadata={"claimed": str(time.time_ns())},
            )
        except ClientError as exc:
            if missing(exc):
                return False
            raise
        return True

    def copy(self, source: str, target: str) -> bool:
        """Copy ``source`` to ``target`` as it is (its metadata kept); False when it is gone."""
        from botocore.exceptions import ClientError

        try:
            self.client.copy_object(
                Bucket=self.name,
                Key=self.key(target),
                CopySource={"Bucket": self.name, "Key": self.key(source)},
            )
        except ClientError as exc:
            if missing(exc):
                return False
            raise
        return True

    def claim_ns(self, relative: str) -> int | None:
        """An object's claim time (its ``claimed`` metadata, else LastModified); None when
        it is not there (one HEAD)."""
        from botocore.exceptions import ClientError

        try:
            head = self.client.head_object(Bucket=self.name, Key=self.key(relative))
        except ClientError as exc:
            if missing(exc):
                return None
            raise
        claimed = head.get("Metadata", {}).get("claimed")
        if claimed and claimed.isdigit():
            return int(claimed)
        return int(head["LastModified"].timestamp() * 1e9)

    # --- reads, listings, deletions ---------------------------------------------------------

    def get(self, relative: str) -> BinaryIO | None:
        """An object's body, to be streamed and closed (one GET); None when it is not there."""
        from botocore.exceptions import ClientError

        try:
            response = self.client.get_object(Bucket=self.name, Key=self.key(relative))
        except ClientError as exc:
            if missing(exc):
                return None
            raise
        body: BinaryIO = response["Body"]
        return body

    def objects(self, relative: str) -> Iterator[dict[str, Any]]:
        """The objects under ``relative`` (a prefix), with their keys, sizes and times."""
        paginator = self.client.get_paginator("list_objects_v2")
        for page in paginator.paginate(Bucket=self.name, Prefix=self.key(relative)):
            yield from page.get("Contents", [])

    def has_any(self, relative: str) -> bool:
        """Whether any object lies under ``relative`` (one listing of one key)."""
        response = self.client.list_objects_v2(
            Bucket=self.name, Prefix=self.key(relative), MaxKeys=1
        )
        return bool(response.get("KeyCount"))

    def delete(self, relative: str) -> None:
        self.client.delete_object(Bucket=self.name, Key=self.key(relative))

    def delete_keys(self, keys: Iterable[str]) -> None:
        """Delete objects by their full keys, a thousand a request (S3's limit)."""
        batch = list(keys)
        for start in range(0, len(batch), 1000):
            chunk = batch[start : start + 1000]
            if chunk:
                self.client.delete_objects(
                    Bucket=self.name,
                    Delete={"Objects": [{"Key": k} for k in chunk], "Quiet": True},
                )


def get_to(client: Any, bucket: str, key: str, path: Path) -> None:
    """Stream one object to ``path``."""
    response = client.get_object(Bucket=bucket, Key=key)
    path.parent.mkdir(parents=True, exist_ok=True)
    with response["Body"] as body, open(path, "wb") as handle:
        shutil.copyfileobj(body, handle, CHUNK)


def download_prefix(url: str, folder: Path, endpoint_url: str | None, *, waits: StoreWaits) -> Path:
    """Copy ``s3://bucket/key`` (one object) or ``s3://bucket/prefix`` (every object under it,
    its folders kept) into ``folder``, streamed to disk; returns the local file or folder
    (named like the key's last part). For ``weldpool import`` and ``import-labels`` from a
    bucket a camera rig or another tool fills, with the store's endpoint and credentials."""
    import os
    import posixpath

    from botocore.exceptions import BotoCoreError, ClientError

    from app.core.errors import InvalidInputError

    bucket, key = parse_url(url)
    client = client_for(endpoint_url, os.environ.get("AWS_REGION"), waits)
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
            get_to(client, bucket, key, target)
            return target
        if not listed:
            raise InvalidInputError(f"{url} holds no objects.")
        for name in listed:
            relative = posixpath.normpath(name.removeprefix(f"{key}/" if key else ""))
            if relative.startswith(("../", "/")) or relative == "..":
                continue  # a key that would land outside the folder
            get_to(client, bucket, name, target / relative)
    except ClientError as exc:
        if missing(exc):
            raise InvalidInputError(f"{url} does not exist.") from None
        raise InvalidInputError(f"{url} cannot be read ({reason(exc, waits)}).") from None
    except BotoCoreError as exc:
        raise InvalidInputError(f"{url} cannot be read ({reason(exc, waits)}).") from None
    return target
