"""/api/v1/users and /api/v1/tokens: who may use weldpool, and their API tokens."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response, status

from app.core.bounds import IdPath
from app.core.db import utcnow
from app.core.deps import SessionDep
from app.core.errors import AuthenticationError, PermissionDeniedError
from app.core.models import User
from app.core.permissions import allowed
from app.core.security import (
    AdminUser,
    CurrentUser,
    ReviewerUser,
    authenticate_throttled,
    optional_user,
)
from app.users import service, work
from app.users.schemas import (
    CsrfOut,
    MeOut,
    PasswordChange,
    PasswordChanged,
    TokenCreated,
    TokenIn,
    TokenOut,
    UserBrief,
    UserIn,
    UserOut,
    UserPatch,
    WorkOut,
)

router = APIRouter(tags=["users"])


@router.get("/users/me", response_model=MeOut)
def me(user: CurrentUser) -> MeOut:
    """The caller, and the actions their role allows (`may`)."""
    return MeOut.model_validate(
        UserOut.model_validate(user).model_dump() | {"may": allowed(user.role)}
    )


@router.get("/users/me/work", response_model=WorkOut)
def my_work(session: SessionDep, user: CurrentUser) -> WorkOut:
    """The caller's work as counts (the header's badge): labels sent back to them, frames handed
    to them still to review, and (reviewers) labels awaiting approval. Each opens its list:
    `GET /frames?assignee=me&review=returned`, `?assignee=me&status=unreviewed`,
    `?review=awaiting`; `GET /frames?assignee=me` alone lists the first two, sent back first."""
    counts = work.work_counts(session, user)
    return WorkOut(
        sent_back=counts.sent_back, assigned=counts.assigned, awaiting_review=counts.awaiting_review
    )


@router.get("/users/me/csrf", response_model=CsrfOut)
def my_csrf_token(request: Request, response: Response, user: CurrentUser) -> CsrfOut:
    """The CSRF token of the caller's browser session (null for an API token) and whose it is:
    a page loaded under an earlier login of the same user sends its changes with it. Readable
    by this origin's pages only."""
    response.headers["Cache-Control"] = "no-store"
    web_session = getattr(request.state, "web_session", None)
    token = web_session.csrf_token if web_session is not None else None
    return CsrfOut(csrf_token=token, username=user.username)


@router.post("/users/me/password", response_model=PasswordChanged)
def change_my_password(
    request: Request, body: PasswordChange, session: SessionDep, user: CurrentUser
) -> PasswordChanged:
    """Change one's own password: the current one is checked under the login throttle (a wrong
    one: 403, then 429). One's other browser sessions end; this one and one's API tokens stay."""
    try:
        authenticate_throttled(request, session, user.username, body.current)
    except AuthenticationError:
        raise PermissionDeniedError("The current password is not right.") from None
    web_session = getattr(request.state, "web_session", None)
    ended, active = service.change_own_password(
        session, user, body.new, web_session.id if web_session is not None else None
    )
    return PasswordChanged(sessions_ended=ended, tokens_active=active)


@router.get("/users/assignable", response_model=list[UserBrief])
def assignable_users(session: SessionDep, _reviewer: ReviewerUser) -> list[UserBrief]:
    """The active users frames can be handed to (reviewers; names and roles only)."""
    return [UserBrief.model_validate(u) for u in service.list_users(session) if u.is_active]


@router.get("/users", response_model=list[UserOut])
def list_users(session: SessionDep, _admin: AdminUser) -> list[UserOut]:
    """Every user (admins only)."""
    return [UserOut.model_validate(u) for u in service.list_users(session)]


@router.post("/users", response_model=UserOut, status_code=status.HTTP_201_CREATED)
def create_user(body: UserIn, session: SessionDep, _admin: AdminUser) -> UserOut:
    """Add a user (admins only)."""
    return UserOut.model_validate(
        service.create_user(session, body.username, body.password, body.role)
    )


@router.patch("/users/{user_id}", response_model=UserOut)
def update_user(
    user_id: IdPath, body: UserPatch, session: SessionDep, _admin: AdminUser
) -> UserOut:
    """Change a user's role, activity or password (admins only)."""
    user = service.get_user(session, user_id)
    return UserOut.model_validate(
        service.update_user(
            session, user, role=body.role, is_active=body.is_active, password=body.password
        )
    )


@router.get("/tokens", response_model=list[TokenOut])
def list_tokens(session: SessionDep, user: CurrentUser) -> list[TokenOut]:
    """The caller's API tokens (never the tokens themselves)."""
    return [TokenOut.model_validate(t) for t in service.list_tokens(session, user)]


tokens_router = APIRouter(tags=["users"])


@tokens_router.post("/tokens", response_model=TokenCreated, status_code=status.HTTP_201_CREATED)
def create_token(
    request: Request,
    session: SessionDep,
    caller: Annotated[User | None, Depends(optional_user)],
    body: TokenIn | None = None,
) -> TokenCreated:
    """A new API token; the answer is the only place the token appears.

    For the user whose ``username`` and ``password`` are in the body (a script with no token
    yet; wrong passwords count towards the login lockout: 401, then 429), else for the caller
    (bearer token, or a logged-in browser with its CSRF token).
    """
    body = body or TokenIn()
    if body.username is not None or body.password is not None:  # the credentials decide
        caller = authenticate_throttled(request, session, body.username or "", body.password or "")
        caller.last_login_at = utcnow()
    if caller is None:
        raise AuthenticationError(
            "Send 'Authorization: Bearer <token>', log in, or give username and password."
        )
    row, text = service.create_token(session, caller, body.name)
    return TokenCreated(token=text, **TokenOut.model_validate(row).model_dump())


@router.delete("/tokens/{token_id}", response_model=TokenOut)
def revoke_token(token_id: IdPath, session: SessionDep, user: CurrentUser) -> TokenOut:
    """Revoke a token (one's own; admins any)."""
    return TokenOut.model_validate(service.revoke_token(session, token_id, user))
