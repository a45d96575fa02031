"""User and token payloads of the REST API."""

from __future__ import annotations

import datetime as dt

from pydantic import BaseModel, ConfigDict, Field

from app.core.bounds import InputModel
from app.core.models import Role

USERNAME_PATTERN = r"^[A-Za-z0-9_.@-]{1,64}$"


class CsrfOut(BaseModel):
    csrf_token: str | None = Field(
        description="The browser session's CSRF token (null when called with an API token)."
    )
    username: str = Field(description="Whose session it is (a page checks it is still its own).")


class UserOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    username: str
    role: Role
    is_active: bool
    created_at: dt.datetime
    last_login_at: dt.datetime | None = Field(
        default=None, description="The last login with the form or a password (never: null)."
    )


class UserBrief(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    username: str
    role: Role


class UserIn(InputModel):
    username: str = Field(pattern=USERNAME_PATTERN)
    password: str = Field(min_length=8, max_length=1024)
    role: Role = Role.annotator


class UserPatch(InputModel):
    role: Role | None = None
    is_active: bool | None = None
    password: str | None = Field(default=None, min_length=8, max_length=1024)


class PasswordChange(InputModel):
    current: str = Field(max_length=1024, description="The password in use now.")
    new: str = Field(min_length=8, max_length=1024)


class PasswordChanged(BaseModel):
    sessions_ended: int = Field(description="The caller's other browser sessions, now logged out.")
    tokens_active: int = Field(
        description="The caller's API tokens, still valid (revoke any you did not make)."
    )


class TokenOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    prefix: str = Field(description="The token's first characters, to recognise it.")
    created_at: dt.datetime
    last_used_at: dt.datetime | None
    revoked_at: dt.datetime | None


class TokenIn(InputModel):
    name: str = Field(default="", max_length=64)
    username: str | None = Field(
        default=None, max_length=64, description="With password: a token for a script."
    )
    password: str | None = Field(default=None, max_length=1024)


class TokenCreated(TokenOut):
    token: str = Field(description="The token itself; shown only in this answer.")


class WorkOut(BaseModel):
    sent_back: int = Field(description="Labels a reviewer sent back to the caller, to correct.")
    assigned: int = Field(
        description="Frames for the caller to label: handed to them still to review, or given "
        "to several annotators with the caller's own label not saved yet."
    )
    awaiting_review: int = Field(
        description="Labels awaiting a reviewer's approval (reviewers; 0 for annotators)."
    )


class MeOut(UserOut):
    """The caller, with what their role allows (``app.core.permissions``): the pages read
    ``may`` rather than ranking roles themselves."""

    may: list[str] = Field(description="The actions the caller's role allows.")
