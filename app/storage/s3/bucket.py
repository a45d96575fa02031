"""One bucket under a prefix, as the object store uses it: keys, claims, transfers and listings.

Every object's key is ``<prefix>/<relative path>``, the same relative path the database holds,
so a row means the same file on every machine. A claim is the object's ``claimed`` metadata (a
copy of the object onto itself sets it to now, and so its LastModified).

Two clients, one bucket: boto3 (the AWS SDK: claims, reads, listings, deletions, multipart
uploads of files, and the standard credential chain) and obstore (Rust's ``object_store``) for
the one request ingest makes per frame, the conditional PUT of bytes held in memory. botocore
spends about 1.5–2.5 ms of Python per PUT, a third of all the web process does for a frame at
home; obstore about 0.5 (``bench/storage.py``). obstore signs with boto3's credentials, and its
failures are raised as botocore's (``botocore_error``), so the rest of the service knows one
kind of store error.
"""

from __future__ import annotations

import datetime as dt
import re
import shutil
import time
from collections.abc import Iterable, Iterator
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO
from urllib.parse import urlparse

from app.core.errors import without_addresses
from app.storage.protocol import CHUNK

if TYPE_CHECKING:
    from obstore.store import ClientConfig

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


@lru_cache(maxsize=16)
def uploads_for(
    bucket: str, endpoint_url: str | None, region: str | None, waits: StoreWaits
) -> Any:
    """obstore's client for ``bucket`` as boto3's is made: its credentials, its CA bundle
    (``AWS_CA_BUNDLE``), the bucket's own region where none is set (boto3 follows AWS's
    redirect; obstore asks once), and the same waits: connect within ``connect_s``, each read
    within ``read_s``."""
    import boto3
    from botocore.exceptions import NoCredentialsError
    from obstore.auth.boto3 import Boto3CredentialProvider
    from obstore.store import S3Store

    session = boto3.Session()
    if session.get_credentials() is None:
        raise NoCredentialsError()
    options: ClientConfig = {
        "allow_http": True,
        "connect_timeout": dt.timedelta(seconds=waits.connect_s),
        "read_timeout": dt.timedelta(seconds=waits.read_s),
        "timeout": dt.timedelta(hours=1),  # a stalled transfer is the read timeout's
    }
    bundle = session._session.get_config_variable("ca_bundle")  # boto3 has no public getter
    if bundle:
        options["root_certificate"] = Path(bundle).read_bytes()
    return S3Store(
        bucket,
        endpoint=endpoint_url or None,
        region=region or session.region_name or _bucket_region(bucket, endpoint_url, waits),
        # a store of its own (MinIO, Ceph) is addressed by path; AWS by host, but for a name
        # with dots (which the wildcard certificate does not cover)
        virtual_hosted_style_request=not endpoint_url and "." not in bucket,
        credential_provider=Boto3CredentialProvider(session),
        client_options=options,
        retry_config={
            "max_retries": waits.attempts - 1,
            "retry_timeout": dt.timedelta(seconds=waits.longest_s),
            "backoff": {
                "init_backoff": dt.timedelta(milliseconds=100),
                "max_backoff": dt.timedelta(seconds=2),
                "base": 2.0,
            },
        },
    )


def _bucket_region(bucket: str, endpoint_url: str | None, waits: StoreWaits) -> str:
    """The bucket's region as its store names it (one HEAD), us-east-1 when it names none."""
    from botocore.exceptions import ClientError

    try:
        answer = client_for(endpoint_url, None, waits).head_bucket(Bucket=bucket)
    except ClientError as exc:  # a 301 from another region's endpoint still names it
        answer = exc.response
    headers = answer.get("ResponseMetadata", {}).get("HTTPHeaders", {})
    return str(headers.get("x-amz-bucket-region") or "us-east-1")


_STATUS = re.compile(r"status code: (\d{3})")
_CODE = re.compile(r"<Code>([^<]{1,64})</Code>")


def botocore_error(exc: Exception, operation: str, endpoint_url: str | None) -> Exception:
    """An obstore failure as botocore would have raised it, so that one set of rules reads
    every store error (``app.core.errors.store_outage``, the 503 of a request): the store's
    answer as a ``ClientError`` with its status and code, no answer as a connection error."""
    from botocore.exceptions import ClientError, EndpointConnectionError
    from obstore.exceptions import PermissionDeniedError, UnauthenticatedError

    text = str(exc)
    status = _STATUS.search(text)
    if isinstance(exc, PermissionDeniedError | UnauthenticatedError) or status:
        number = int(status.group(1)) if status else 403
        code = _CODE.search(text)
        answer = {
            "Error": {
                "Code": code.group(1) if code else str(number),
                "Message": "the store refused the upload" if number < 500 else "",
            },
            "ResponseMetadata": {"HTTPStatusCode": number},
        }
        return ClientError(answer, operation)
    return EndpointConnectionError(endpoint_url=endpoint_url or "the object store")


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
        self.endpoint_url = endpoint_url
        self.region = region
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
        through obstore); returns the new object's claim time, or None when an object is there
        already."""
        import obstore
        from obstore.exceptions import AlreadyExistsError, BaseError, PreconditionError

        claimed = time.time_ns()
        uploads = uploads_for(self.name, self.endpoint_url, self.region, self.waits)
        try:
            obstore.put(
                uploads,
                self.key(relative),
                data,
                attributes={"claimed": str(claimed)},
                mode="create",
                use_multipart=False,
            )
        except (AlreadyExistsError, PreconditionError):  # 412, or 409: another's PUT of it
            return None
        except (BaseError, OSError) as exc:  # obstore raises a missing bucket as FileNotFound
            raise botocore_error(exc, "PutObject", self.endpoint_url) from None
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
