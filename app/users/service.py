"""Users and their API tokens (the REST API and the CLI both call these)."""

from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import commit_or_conflict, utcnow
from app.core.errors import ConflictError, InvalidInputError, NotFoundError, PermissionDeniedError
from app.core.models import ApiToken, Role, User, WebSession
from app.core.permissions import Action, may
from app.core.security import (
    MADE_PASSWORD_BYTES,
    hash_made_password,
    hash_password,
    issue_token,
    user_named,
    verify_password,
)
from app.users.schemas import USERNAME_PATTERN

MIN_PASSWORD_LENGTH = 8


def _check_password(password: str) -> None:
    if len(password) < MIN_PASSWORD_LENGTH:
        raise InvalidInputError(
            f"The password must have at least {MIN_PASSWORD_LENGTH} characters."
        )


def create_user(
    session: Session, username: str, password: str, role: Role, *, made: bool = False
) -> User:
    """A new active user; the name must be free. ``made``: the password was made here from
    ``MADE_PASSWORD_BYTES`` random bytes, not chosen by a person (hashed with
    ``app.core.security.MADE``'s cheap parameters)."""
    if not re.fullmatch(USERNAME_PATTERN, username):
        raise InvalidInputError(
            "A user name has 1 to 64 letters, digits or the characters _ . @ -."
        )
    _check_password(password)
    taken = session.scalar(  # a name is one user in any case
        sa.select(User).where(sa.func.lower(User.username) == username.lower()).limit(1)
    )
    if taken is not None:
        raise ConflictError(f"There is already a user named {taken.username!r}.")
    password_hash = hash_made_password(password) if made else hash_password(password)
    user = User(username=username, password_hash=password_hash, role=role)
    session.add(user)
    commit_or_conflict(session, f"There is already a user named {username!r}.")
    return user


def get_user(session: Session, user_id: int) -> User:
    user = session.get(User, user_id)
    if user is None:
        raise NotFoundError(f"There is no user {user_id}.")
    return user


def user_by_name(session: Session, username: str) -> User:
    """The user of a name, in any case (``app.core.security.user_named``)."""
    user = user_named(session, username)
    if user is None:
        raise NotFoundError(
            f"There is no user named {username!r}; add one with `weldpool user add`."
        )
    return user


def list_users(session: Session) -> list[User]:
    return list(session.scalars(sa.select(User).order_by(User.username)).all())


def _lock_admins(session: Session, user: User) -> None:
    """Lock the active admins' rows until the commit, then read ``user`` afresh: a concurrent
    change of an admin waits here, and the count after it sees that change committed
    (PostgreSQL: FOR UPDATE; SQLite: a write takes the database's one writer lock, so the
    transaction begins with a write before anything is counted)."""
    if session.get_bind().dialect.name == "sqlite":
        session.execute(sa.update(User).where(User.id == user.id).values(role=User.role))
    else:
        admins = sa.select(User.id).where(User.role == Role.admin, User.is_active.is_(True))
        session.execute(admins.order_by(User.id).with_for_update())
    session.refresh(user)


def _log_out_everywhere(session: Session, user: User) -> None:
    """End the user's browser sessions and revoke their API tokens (for good: a reactivation
    revives none of them)."""
    session.execute(sa.delete(WebSession).where(WebSession.user_id == user.id))
    session.execute(
        sa.update(ApiToken)
        .where(ApiToken.user_id == user.id, ApiToken.revoked_at.is_(None))
        .values(revoked_at=utcnow())
    )


def update_user(
    session: Session,
    user: User,
    *,
    role: Role | None = None,
    is_active: bool | None = None,
    password: str | None = None,
) -> User:
    """Change a user's role, activity or password.

    A new password or deactivation logs the user out everywhere: their browser sessions end and
    their API tokens are revoked (a reset after a leak must lock the old credentials out; a
    reactivation revives none of them).
    A change of role or activity first locks the active admins' rows (``_lock_admins``), so
    two admins demoting each other at once cannot both pass the "one admin stays" count.
    """
    if role is not None or is_active is not None:
        _lock_admins(session, user)
    if role is not None:
        user.role = role
    if password is not None:
        _check_password(password)
        user.password_hash = hash_password(password)
    if is_active is not None:
        user.is_active = is_active
    if password is not None or is_active is False:
        _log_out_everywhere(session, user)
    if not session.scalar(
        sa.select(sa.func.count()).where(User.role == Role.admin, User.is_active.is_(True))
    ):
        session.rollback()
        raise ConflictError("This would leave no active admin; promote another user first.")
    session.commit()
    return user


def change_own_password(
    session: Session, user: User, new: str, keep_session_id: int | None
) -> tuple[int, int]:
    """A user's own new password (the current one checked by the caller, under the login
    throttle). Their other browser sessions end, the one making the change stays (``keep``);
    their API tokens stay, listed beside the form to revoke. Returns (sessions ended, tokens
    still active)."""
    _check_password(new)
    if verify_password(user.password_hash, new):
        raise InvalidInputError("The new password is the one in use; choose another.")
    user.password_hash = hash_password(new)
    others = [WebSession.user_id == user.id]
    if keep_session_id is not None:
        others.append(WebSession.id != keep_session_id)
    ended = session.scalar(sa.select(sa.func.count()).select_from(WebSession).where(*others))
    session.execute(sa.delete(WebSession).where(*others))
    active = session.scalar(
        sa.select(sa.func.count())
        .select_from(ApiToken)
        .where(ApiToken.user_id == user.id, ApiToken.revoked_at.is_(None))
    )
    session.commit()
    return int(ended or 0), int(active or 0)


def create_token(session: Session, user: User, name: str = "") -> tuple[ApiToken, str]:
    """A new API token for ``user``; the text is returned once and stored only hashed."""
    row, text = issue_token(session, user, name)
    session.commit()
    return row, text


def list_tokens(session: Session, user: User) -> list[ApiToken]:
    return list(
        session.scalars(
            sa.select(ApiToken).where(ApiToken.user_id == user.id).order_by(ApiToken.id)
        ).all()
    )


def revoke_token(session: Session, token_id: int, actor: User | None) -> ApiToken:
    """Revoke a token; users revoke their own, admins any (``actor`` None: the CLI)."""
    row = session.get(ApiToken, token_id)
    if row is None:
        raise NotFoundError(f"There is no token {token_id}.")
    if actor is not None and row.user_id != actor.id and not may(actor, Action.administer):
        raise PermissionDeniedError("Only admins may revoke other users' tokens.")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
        session.commit()
    return row


INITIAL_ADMIN = "admin"
INITIAL_PASSWORD_FILE = "initial-admin-password"


def ensure_initial_admin(session: Session, home: Path) -> Path | None:
    """On a fresh instance (no users at all), create ``admin`` with a random password.

    The password goes to a file readable only by its owner in ``home`` (never to the log);
    returns that file's path, or None when users already exist.
    """
    if session.scalar(sa.select(sa.func.count()).select_from(User)):
        return None
    password = secrets.token_urlsafe(MADE_PASSWORD_BYTES)
    create_user(session, INITIAL_ADMIN, password, Role.admin, made=True)
    path = home / INITIAL_PASSWORD_FILE
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "w") as handle:
        handle.write(password + "\n")
    return path


def importing_user(session: Session, username: str | None) -> User:
    """Who a command-line import records as the labels' author: the user named, else the
    first admin."""
    if username:
        return user_by_name(session, username)
    admin = session.scalar(
        sa.select(User).where(User.role == Role.admin, User.is_active).order_by(User.id)
    )
    if admin is None:
        raise NotFoundError("There is no admin to import as; name one with --user.")
    return admin
