"""Passwords, API tokens, browser sessions, CSRF and role checks."""

from __future__ import annotations

import collections
import dataclasses
import datetime as dt
import functools
import hashlib
import hmac
import math
import secrets
import threading
import time
from typing import Annotated

import sqlalchemy as sa
from argon2 import Parameters, PasswordHasher, extract_parameters, profiles
from argon2.exceptions import VerificationError
from fastapi import Depends, Request
from sqlalchemy.orm import Session

from app.core.db import utcnow
from app.core.deps import SessionDep
from app.core.errors import AuthenticationError, PermissionDeniedError, TooManyAttemptsError
from app.core.models import ApiToken, User, WebSession
from app.core.permissions import PERMISSIONS, Action, may

SESSION_COOKIE = "weldpool_session"
LOGIN_CSRF_COOKIE = "weldpool_login_csrf"
CSRF_HEADER = "X-CSRF-Token"
TOKEN_PREFIX = "wp_"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

STANDARD = profiles.RFC_9106_LOW_MEMORY
"""The parameters of every password a person sets: RFC 9106's (64 MiB, 3 passes, 4 lanes; ~0.1-0.2
s a hash here)."""
MADE = dataclasses.replace(STANDARD, time_cost=1, memory_cost=1024, parallelism=1)
"""The parameters of a password weldpool makes itself from ``MADE_PASSWORD_BYTES`` random bytes
(a fresh instance's admin's, in a file): 128 random bits cannot be guessed however fast their
hash (the memory-hard cost is for passwords people choose), so a first start does not wait for
the standard hash (~1 ms). Checking one still costs a standard hash (``authenticate``), and its
first right use re-hashes it with ``STANDARD``."""
MADE_PASSWORD_BYTES = 16
_hasher = PasswordHasher.from_parameters(STANDARD)
_made_hasher = PasswordHasher.from_parameters(MADE)


def hash_password(password: str) -> str:
    """An Argon2id hash of ``password`` with the standard parameters."""
    return _hasher.hash(password)


def hash_made_password(password: str) -> str:
    """An Argon2id hash, with the ``MADE`` parameters, of a password this instance made from
    ``MADE_PASSWORD_BYTES`` random bytes (never of one a person chose)."""
    return _made_hasher.hash(password)


def hash_parameters(password_hash: str) -> Parameters | None:
    """A stored hash's parameters, or None where it does not parse."""
    try:
        return extract_parameters(password_hash)
    except ValueError:  # InvalidHashError, or text that is not ASCII
        return None


def verify_password(password_hash: str, password: str) -> bool:
    """Whether ``password`` matches; never raises for a wrong or malformed hash."""
    try:
        return _hasher.verify(password_hash, password)
    except (VerificationError, ValueError):  # ValueError: InvalidHashError, non-ASCII text
        return False


def _sha256(value: str) -> str:
    return hashlib.sha256(value.encode()).hexdigest()


def constant_time_equal(a: str, b: str) -> bool:
    """Compare two secrets without leaking where they differ."""
    return hmac.compare_digest(a.encode(), b.encode())


def new_csrf_token() -> str:
    """A random token for a form or a session."""
    return secrets.token_urlsafe(32)


# --- API tokens ------------------------------------------------------------------------------


def issue_token(session: Session, user: User, name: str = "") -> tuple[ApiToken, str]:
    """Create a token for ``user``; returns the row and the token text (shown only once)."""
    text = TOKEN_PREFIX + secrets.token_urlsafe(32)
    row = ApiToken(user_id=user.id, name=name, token_hash=_sha256(text), prefix=text[:10])
    session.add(row)
    session.flush()
    return row, text


def user_for_token(session: Session, text: str) -> User:
    """The active user owning an unrevoked token, or an AuthenticationError."""
    row = session.scalar(sa.select(ApiToken).where(ApiToken.token_hash == _sha256(text)))
    if row is None or row.revoked_at is not None or not row.user.is_active:
        raise AuthenticationError("The API token is invalid or revoked; create a new one.")
    now = utcnow()
    if row.last_used_at is None or now - row.last_used_at > dt.timedelta(minutes=1):
        row.last_used_at = now
        session.commit()
    return row.user


# --- browser sessions ------------------------------------------------------------------------


def open_web_session(session: Session, user: User, ttl_hours: float) -> tuple[WebSession, str]:
    """Log ``user`` in; returns the session row and the cookie value."""
    cookie = secrets.token_urlsafe(32)
    session.execute(sa.delete(WebSession).where(WebSession.expires_at <= utcnow()))
    row = WebSession(
        user_id=user.id,
        session_hash=_sha256(cookie),
        csrf_token=new_csrf_token(),
        expires_at=utcnow() + dt.timedelta(hours=ttl_hours),
    )
    session.add(row)
    session.flush()
    return row, cookie


def web_session_for_cookie(session: Session, cookie: str) -> WebSession | None:
    """The live session for a cookie value, or None when unknown or expired."""
    row = session.scalar(sa.select(WebSession).where(WebSession.session_hash == _sha256(cookie)))
    if row is None or row.expires_at <= utcnow() or not row.user.is_active:
        return None
    return row


def close_web_session(session: Session, cookie: str) -> None:
    """Log out: forget the session behind a cookie."""
    session.execute(sa.delete(WebSession).where(WebSession.session_hash == _sha256(cookie)))


@functools.cache
def _decoy_hash() -> str:
    """A hash no password matches, checked for unknown names (made once per process)."""
    return hash_password(secrets.token_urlsafe(32))


def user_named(session: Session, username: str) -> User | None:
    """The user a name means, in any case: the one whose name matches it in any case, or of
    two such (a database older than migration 0019 may hold names differing by case alone)
    the one named exactly so; another spelling then means neither."""
    found = session.scalars(
        sa.select(User).where(sa.func.lower(User.username) == username.lower())
    ).all()
    exact = [user for user in found if user.username == username]
    return exact[0] if exact else (found[0] if len(found) == 1 else None)


def authenticate(session: Session, username: str, password: str) -> User | None:
    """The active user with these credentials, or None. An unknown name, a deactivated account
    and a wrong password cost the same one standard hash check, so that timing tells none apart:
    a wrong password against a hash cheaper to check (a made password's, or one that does not
    parse) is checked against the decoy as well. A right password whose hash has other than the
    standard parameters is re-hashed with them (the caller commits), only where the stored hash
    is still the one checked: a password changed meanwhile by another request stays changed."""
    user = user_named(session, username)
    stored = user.password_hash if user else _decoy_hash()
    matches = verify_password(stored, password)
    parameters = hash_parameters(stored)
    if user is not None and matches and parameters != STANDARD:
        session.execute(
            sa.update(User)
            .where(User.id == user.id, User.password_hash == stored)
            .values(password_hash=hash_password(password))
        )
    elif not matches and parameters in (MADE, None):
        verify_password(_decoy_hash(), password)
    if user is None or not user.is_active or not matches:
        return None
    return user


class LoginThrottle:
    """Failed logins per user name and per client address in a sliding window.

    After ``max_failures`` wrong passwords for one name (or 4× that from one address) within
    ``window_s``, ``retry_after`` says how long to wait, and the login is refused before any
    password is hashed (so guessing costs the server nothing). A success clears the name. The
    counts live in this process: behind several web processes each counts its own.
    """

    def __init__(self, max_failures: int, window_s: float) -> None:
        self.max_failures, self.window_s = max_failures, window_s
        self._failures: dict[str, collections.deque[float]] = {}
        self._lock = threading.Lock()

    def _recent(self, key: str, now: float) -> collections.deque[float]:
        times = self._failures.setdefault(key, collections.deque())
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def _keys(self, username: str, address: str) -> tuple[tuple[str, int], tuple[str, int]]:
        return (f"user:{username.lower()}", self.max_failures), (
            f"addr:{address}",
            4 * self.max_failures,
        )

    def retry_after(self, username: str, address: str) -> float:
        """Seconds until a login for this name from this address is allowed again (0: now)."""
        now = time.monotonic()
        with self._lock:
            waits = [
                times[0] + self.window_s - now
                for key, limit in self._keys(username, address)
                if len(times := self._recent(key, now)) >= limit
            ]
        return max(waits, default=0.0)

    def failed(self, username: str, address: str) -> None:
        now = time.monotonic()
        with self._lock:
            for key, _ in self._keys(username, address):
                self._recent(key, now).append(now)
            if len(self._failures) > 100_000:  # bound memory under a spray of names
                self._failures = {k: v for k, v in self._failures.items() if self._recent(k, now)}

    def succeeded(self, username: str) -> None:
        with self._lock:
            self._failures.pop(f"user:{username.lower()}", None)


def authenticate_throttled(
    request: Request, session: Session, username: str, password: str
) -> User:
    """Check a name and password under the login throttle (the one rule for the login page and
    ``POST /tokens``): TooManyAttemptsError while locked out, AuthenticationError when wrong."""
    throttle: LoginThrottle = request.app.state.login_throttle
    address = request.client.host if request.client else ""
    wait = throttle.retry_after(username, address)
    if wait > 0:
        minutes = max(1, math.ceil(wait / 60))
        raise TooManyAttemptsError(
            f"Too many wrong passwords; try again in {minutes} minute{'s' * (minutes > 1)}.", wait
        )
    user = authenticate(session, username, password)
    if user is None:
        throttle.failed(username, address)
        raise AuthenticationError("Wrong user name or password.")
    throttle.succeeded(username)
    return user


# --- FastAPI dependencies --------------------------------------------------------------------


async def sent_csrf_token(request: Request) -> str:
    """The CSRF token a request carries: the X-CSRF-Token header, or a plain form's field."""
    sent = request.headers.get(CSRF_HEADER, "")
    content_type = request.headers.get("content-type", "")
    if (
        not sent
        and request.method not in SAFE_METHODS
        and content_type.startswith("application/x-www-form-urlencoded")
    ):
        form = await request.form()  # Starlette caches it: the route reads the same form
        value = form.get("csrf_token")
        sent = value if isinstance(value, str) else ""
    return sent


def optional_user(
    request: Request, session: SessionDep, sent_csrf: Annotated[str, Depends(sent_csrf_token)]
) -> User | None:
    """The caller: by bearer token, else by session cookie (with CSRF on unsafe methods)."""
    header = request.headers.get("authorization", "")
    if header:
        scheme, _, credentials = header.partition(" ")
        if scheme.lower() != "bearer" or not credentials.strip():
            raise AuthenticationError("The Authorization header must be 'Bearer <token>'.")
        return user_for_token(session, credentials.strip())
    cookie = request.cookies.get(SESSION_COOKIE)
    if not cookie:
        return None
    web_session = web_session_for_cookie(session, cookie)
    if web_session is None:
        return None
    if request.method not in SAFE_METHODS and not constant_time_equal(
        sent_csrf, web_session.csrf_token
    ):
        raise StaleCsrfToken()
    request.state.web_session = web_session
    return web_session.user


class StaleCsrfToken(PermissionDeniedError):
    """A browser request whose CSRF token is not its session's (the page was loaded under an
    earlier login): the body says ``"reason": "csrf"``, so the page can fetch the session's
    token (``GET /users/me/csrf``) and send the request again."""

    def __init__(self) -> None:
        super().__init__(
            f"The {CSRF_HEADER} header is missing or wrong; reload the page and try again."
        )
        self.extra = {"reason": "csrf"}


def current_user(user: Annotated[User | None, Depends(optional_user)]) -> User:
    """The caller, or 401."""
    if user is None:
        raise AuthenticationError(
            "Authentication required: send 'Authorization: Bearer <token>' or log in at /login."
        )
    return user


CurrentUser = Annotated[User, Depends(current_user)]


def require(action: Action) -> object:
    """A dependency that lets through users whose role may do ``action``
    (``app.core.permissions``)."""

    def check(user: CurrentUser) -> User:
        if not may(user, action):
            raise PermissionDeniedError(
                f"This needs the {PERMISSIONS[action].value} role or higher; "
                f"you are {user.role.value}."
            )
        return user

    return Depends(check)


ReviewerUser = Annotated[User, require(Action.review)]
AdminUser = Annotated[User, require(Action.administer)]
