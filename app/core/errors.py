"""Typed errors of the service; each maps to one HTTP status and one clear sentence."""

from __future__ import annotations

import os
import re
from pathlib import Path

from weldpool_core.errors import InvalidInputError, WeightsUnavailableError, WeldpoolError

__all__ = [
    "AuthenticationError",
    "ConfigurationError",
    "ConflictError",
    "InvalidInputError",
    "MissingFile",
    "NotFoundError",
    "PermissionDeniedError",
    "TooManyAttemptsError",
    "WeightsUnavailableError",
    "WeldpoolError",
    "failure_sentence",
    "http_status_of",
    "without_addresses",
    "without_server_paths",
]

_ADDRESS = re.compile(r"""["']?\bhttps?://[^\s"'<>]+["']?""")
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~:/])/([^\s/'\"]+)(?:/[^\s/'\"]+)+")


def _server_path_tail(match: re.Match[str]) -> str:
    """A path's last part when it starts at a folder of this server's root (``/usr``, ``/tmp``,
    …); anything else (an API path, a ratio) as it was."""
    path = match.group(0)
    return path.rsplit("/", 1)[-1] if os.path.isdir(f"/{match.group(1)}") else path


def without_addresses(text: str) -> str:
    """``text`` without the http(s) addresses of servers (botocore's messages quote the object
    store's endpoint URL, credentials and all where it holds them)."""
    return _ADDRESS.sub("its address", text)


def without_server_paths(text: str, home: Path) -> str:
    """A message as any user may read it: paths under the home folder relative to it, other
    absolute paths of the server reduced to their last part, no server's address (the log
    keeps them whole)."""
    for prefix in {f"{home}{os.sep}", f"{home.resolve()}{os.sep}"}:
        text = text.replace(prefix, "")
    return _ABSOLUTE_PATH.sub(_server_path_tail, without_addresses(text))


_STORE_CLIENTS = ("botocore", "boto3", "s3transfer")


_OUTAGE_CODES = {
    "SlowDown",
    "ServiceUnavailable",
    "InternalError",
    "RequestTimeout",
    "Throttling",
    "ConditionalRequestConflict",  # another writer's PUT of the same key, under way for long
}
_NO_ANSWER = {"ConnectionError", "HTTPClientError"}
"""botocore's exceptions for a store that did not answer (connection refused or closed, timeouts):
every one derives from one of these."""


def store_outage(exc: BaseException) -> bool:
    """Whether ``exc`` is the object store or the network failing (no answer, a timeout, a 5xx,
    throttling), not the work: a job pauses and runs again rather than failing, and no frame is
    marked as failed for it."""
    if isinstance(exc, ConnectionError | TimeoutError):
        return True
    if type(exc).__module__.partition(".")[0] not in _STORE_CLIENTS:
        return False
    if any(cls.__name__ in _NO_ANSWER for cls in type(exc).__mro__):
        return True
    response = getattr(exc, "response", None) or {}
    status = response.get("ResponseMetadata", {}).get("HTTPStatusCode") or 0
    return int(status) >= 500 or response.get("Error", {}).get("Code") in _OUTAGE_CODES


def failure_sentence(exc: BaseException) -> str:
    """One sentence for a failure a user reads on a job or a frame: ours as written, the object
    store's in words (what it answered, not where it is), anything else with its type."""
    if isinstance(exc, WeldpoolError):
        return exc.message
    if type(exc).__module__.partition(".")[0] in _STORE_CLIENTS:
        code = (getattr(exc, "response", None) or {}).get("Error", {}).get("Code")
        return (
            f"The object store failed ({code or type(exc).__name__}); check that it runs and "
            "answers at WELDPOOL_S3_ENDPOINT_URL, then run this again."
        )
    return f"Unexpected error ({type(exc).__name__}): {exc}"


class ConfigurationError(WeldpoolError):
    """The service is configured wrongly (a setting, an unmigrated database)."""


class NotFoundError(WeldpoolError):
    """The addressed object does not exist."""


class ConflictError(WeldpoolError):
    """The request conflicts with the current state (a stale revision, a duplicate name)."""


class MissingFile(ConflictError, FileNotFoundError):
    """A row names a stored file the store no longer holds (lost from disk or from the bucket,
    and absent from this machine's cache). The storage layer raises it with the path; a reader
    that knows whose file it is says so (``about``). A FileNotFoundError too, so the code that
    tells a frame deleted meanwhile from a lost file sees it as it saw the bare error."""

    def __init__(self, path: str, message: str | None = None) -> None:
        super().__init__(
            message
            or f"The stored file {path} is missing; run `weldpool doctor` to list the lost "
            "files and what restores each."
        )
        self.path = path

    def about(self, whose: str, restore: str) -> MissingFile:
        """The same loss, said of its owner: ``whose`` ("Frame 12's image") and what restores
        it ("upload the same image again")."""
        sentence = f"{whose} ({self.path}) is missing from the store; {restore}."
        return MissingFile(self.path, sentence)


class AuthenticationError(WeldpoolError):
    """No valid credentials were given."""


class PermissionDeniedError(WeldpoolError):
    """The user is known but their role does not allow this."""


class TooManyAttemptsError(WeldpoolError):
    """Too many wrong passwords for a name or from an address; ``retry_after`` in seconds."""

    def __init__(self, message: str, retry_after: float) -> None:
        super().__init__(message)
        self.retry_after = retry_after


_STATUS: dict[type[WeldpoolError], int] = {
    InvalidInputError: 400,
    AuthenticationError: 401,
    PermissionDeniedError: 403,
    NotFoundError: 404,
    ConflictError: 409,
    TooManyAttemptsError: 429,
    WeightsUnavailableError: 503,
    ConfigurationError: 503,
}


def http_status_of(error: WeldpoolError) -> int:
    """The HTTP status for a typed error (400 for any other user-facing error)."""
    for cls in type(error).__mro__:
        if cls in _STATUS:
            return _STATUS[cls]
    return 400
