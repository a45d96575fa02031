"""The one request ingest makes per frame, its conditional PUT, through obstore (Rust's
``object_store``) instead of botocore, whose Python costs about 1.5–2.5 ms a request, a third of
all the web process does for a frame at home; obstore about 0.5 (``bench/storage.py``).

obstore's client is set up as boto3's is, so that the two clients of one bucket agree:

- **where**: the endpoint boto3 resolved (``WELDPOOL_S3_ENDPOINT_URL`` or ``AWS_ENDPOINT_URL``;
  a store of its own is addressed by path, AWS by host but for dotted names), and the bucket's
  own region, asked once (boto3 follows AWS's redirect to it; obstore does not);
- **who**: boto3's credential chain, read again well before temporary credentials expire;
- **trust**: ``AWS_CA_BUNDLE`` (or the profile's ``ca_bundle``) for a store behind a private CA;
- **waits and errors**: ``StoreWaits`` (connect, each read, attempts with backoff on no answer,
  timeouts, 5xx and throttling; obstore itself retries none), and every failure raised as the
  botocore error the rest of the service reads (``app.core.errors.store_outage``, the 503 of a
  request), the store's own words logged without its address.
"""

from __future__ import annotations

import datetime as dt
import re
import time
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog

from app.core.errors import ConfigurationError, without_addresses

if TYPE_CHECKING:
    from obstore.store import ClientConfig, S3Store

    from app.core.config import StoreWaits

log = structlog.get_logger(__name__)

_STATUS = re.compile(r"status code: (\d{3})")
_CODE = re.compile(r"<Code>([^<]{1,64})</Code>")
_MESSAGE = re.compile(r"<Message>([^<]{1,200})</Message>")
_CONFLICTS = {"PreconditionFailed", "ConditionalRequestConflict"}
"""The store's words for "this key is there, or being written": the caller claims it."""
_RETRIED_CODES = {"SlowDown", "Throttling", "RequestTimeout", "RequestTimeTooSkewed"}


class Credentials:
    """boto3's credentials for obstore. obstore keeps an answer until its ``expires_at``; an
    answer from refreshable credentials (instance roles, SSO, AssumeRole) is kept 5 minutes,
    well within the 10 that botocore leaves them at least."""

    def __init__(self, credentials: Any) -> None:
        self.credentials = credentials

    def __call__(self) -> dict[str, Any]:
        from botocore.credentials import RefreshableCredentials

        frozen = self.credentials.get_frozen_credentials()
        refreshable = isinstance(self.credentials, RefreshableCredentials)
        return {
            "access_key_id": frozen.access_key,
            "secret_access_key": frozen.secret_key,
            "token": frozen.token,
            "expires_at": dt.datetime.now(dt.UTC) + dt.timedelta(minutes=5)
            if refreshable
            else None,
        }

    def raise_boto3s_error(self) -> None:
        """After obstore could not get them: raise what boto3 raises getting them here (an
        expired SSO token, no instance role), in this thread; nothing when they come now."""
        self.credentials.get_frozen_credentials()


_AWS = re.compile(r"^https://s3([.-][a-z0-9-]+)?\.amazonaws\.com/?$")
"""AWS's own S3 endpoints, as boto3 resolves them when none is configured (obstore makes the
same from the region; China's and any other are given to it as they are)."""


@lru_cache(maxsize=16)
def uploads_for(bucket: str, client: Any, waits: StoreWaits) -> tuple[S3Store, Credentials]:
    """obstore's client for ``bucket``, made from boto3's ``client`` of it (module doc)."""
    import boto3
    from botocore.exceptions import NoCredentialsError
    from obstore.store import S3Store

    session = boto3.Session()
    found = session.get_credentials()
    if found is None:
        raise NoCredentialsError()
    credentials = Credentials(found)
    endpoint = str(client.meta.endpoint_url)
    aws = _AWS.match(endpoint) is not None  # a configured one (MinIO, PrivateLink) is used as is
    options: ClientConfig = {
        "allow_http": True,
        "connect_timeout": dt.timedelta(seconds=waits.connect_s),
        "read_timeout": dt.timedelta(seconds=waits.read_s),
        "timeout": dt.timedelta(hours=1),  # a stalled transfer is the read timeout's
    }
    bundle = session._session.get_config_variable("ca_bundle")  # boto3 has no public getter
    if bundle:
        try:
            options["root_certificate"] = Path(bundle).read_bytes()
        except OSError as exc:
            raise ConfigurationError(
                f"The object store's CA bundle (AWS_CA_BUNDLE, {bundle}) cannot be read: "
                f"{exc.strerror or exc}."
            ) from None
    where: dict[str, Any] = (
        {"virtual_hosted_style_request": "." not in bucket}  # the wildcard certificate
        if aws
        else {"endpoint": endpoint, "virtual_hosted_style_request": False}
    )
    store = S3Store(
        bucket,
        region=bucket_region(client, bucket),
        credential_provider=credentials,  # type: ignore[arg-type]
        client_options=options,
        retry_config={"max_retries": 0, "retry_timeout": dt.timedelta(seconds=waits.longest_s)},
        **where,
    )
    return store, credentials


def bucket_region(client: Any, bucket: str) -> str:
    """The bucket's region as its store names it (one HEAD), else the client's own, else
    us-east-1. A store that fails the HEAD (5xx, throttling) fails this too: nothing is
    guessed and kept."""
    from botocore.exceptions import ClientError

    try:
        answer = client.head_bucket(Bucket=bucket)
    except ClientError as exc:  # a 301 or 403 from AWS still names it
        answer = exc.response
        headers = answer.get("ResponseMetadata", {}).get("HTTPHeaders", {})
        if "x-amz-bucket-region" not in headers and _retried(exc):
            raise
    headers = answer.get("ResponseMetadata", {}).get("HTTPHeaders", {})
    return str(headers.get("x-amz-bucket-region") or client.meta.region_name or "us-east-1")


def create(
    client: Any, bucket: str, key: str, data: bytes, claimed: int, waits: StoreWaits
) -> bool:
    """PUT ``data`` at ``key`` with ``claimed`` as its metadata unless the key exists
    (``If-None-Match: *``); False when it does (or another writer's PUT of it is under way).
    Tried ``waits.attempts`` times on no answer, a timeout, a 5xx or throttling: safe, as an
    attempt that landed makes the next one find the key."""
    import obstore
    from obstore.exceptions import (
        AlreadyExistsError,
        BaseError,
        PreconditionError,
        UnauthenticatedError,
    )

    # one client per bucket and process (its region asked once); not under a lock, so that
    # a store that hangs holds each of ingest's threads its own bound, at once
    store, credentials = uploads_for(bucket, client, waits)
    for attempt in range(waits.attempts):
        try:
            obstore.put(
                store,
                key,
                data,
                attributes={"claimed": str(claimed)},
                mode="create",
                use_multipart=False,
            )
            return True
        except (AlreadyExistsError, PreconditionError) as exc:
            code = _CODE.search(str(exc))
            if code is None or code.group(1) in _CONFLICTS:
                return False
            error = botocore_error(exc, client.meta.endpoint_url)  # another 409 or 412
        except (BaseError, OSError) as exc:
            if isinstance(exc, UnauthenticatedError) and "credential" in str(exc).lower():
                credentials.raise_boto3s_error()  # boto3's own words; else a passing glitch
            error = botocore_error(exc, client.meta.endpoint_url)
        log.warning("storage.put_failed", key=key, attempt=attempt + 1, error=_words(error))
        if not _retried(error) or attempt + 1 == waits.attempts:
            raise error from None
        time.sleep(min(2.0, 0.1 * 2**attempt))
    raise AssertionError("unreachable")  # pragma: no cover


def _words(error: Exception) -> str:
    return without_addresses(str(getattr(error, "obstore_text", error)))[:500]


def botocore_error(exc: Exception, endpoint_url: str | None) -> Exception:
    """An obstore failure as botocore would have raised it: the store's answer as a
    ``ClientError`` with its status and code, a timeout as ``ReadTimeoutError``, no answer as
    ``EndpointConnectionError`` (obstore's own text kept as ``obstore_text`` for the log)."""
    from botocore.exceptions import ClientError, EndpointConnectionError, ReadTimeoutError
    from obstore.exceptions import PermissionDeniedError, UnauthenticatedError

    text = str(exc)
    status = _STATUS.search(text)
    number = int(status.group(1)) if status else None
    if number is None and "redirect" in text.lower():
        number = 301  # another region's endpoint (obstore does not follow it)
    error: Exception
    if isinstance(exc, UnauthenticatedError) and "credential" in text.lower():
        # obstore could not get the credentials, but boto3 then could: a passing glitch
        error = EndpointConnectionError(endpoint_url=endpoint_url or "the object store")
    elif isinstance(exc, PermissionDeniedError | UnauthenticatedError) or number:
        number = number or 403
        code, message = _CODE.search(text), _MESSAGE.search(text)
        default = "PermanentRedirect" if number == 301 else str(number)
        answer = {
            "Error": {
                "Code": code.group(1) if code else default,
                "Message": message.group(1) if message else "",
            },
            "ResponseMetadata": {"HTTPStatusCode": number},
        }
        error = ClientError(answer, "PutObject")
    elif "Timeout" in text or "timed out" in text:
        error = ReadTimeoutError(endpoint_url=endpoint_url or "the object store")
    else:
        error = EndpointConnectionError(endpoint_url=endpoint_url or "the object store")
    error.obstore_text = text  # type: ignore[attr-defined]
    return error


def _retried(error: Exception) -> bool:
    """Whether boto3's standard retries would try again after ``error``."""
    response = getattr(error, "response", None)
    if response is None:
        return True  # no answer or a timeout
    status = int(response.get("ResponseMetadata", {}).get("HTTPStatusCode") or 0)
    code = response.get("Error", {}).get("Code")
    return status in {500, 502, 503, 504} or code in _RETRIED_CODES
