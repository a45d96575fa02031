"""Browser pages: login and logout, the frame list, the review page, jobs and models.

Each page is a template plus one ES module under static/js/ that calls the REST API; these
routes only check the login and render (no data is loaded here)."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from fastapi import APIRouter, Depends, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from app.core.bounds import IdPath
from app.core.db import utcnow
from app.core.deps import SessionDep, SettingsDep
from app.core.errors import AuthenticationError, TooManyAttemptsError
from app.core.models import User
from app.core.permissions import Action, allowed, may
from app.core.security import (
    LOGIN_CSRF_COOKIE,
    SESSION_COOKIE,
    authenticate_throttled,
    close_web_session,
    constant_time_equal,
    current_user,
    new_csrf_token,
    open_web_session,
    optional_user,
)
from app.labelconfig.schemas import REVIEW_KEYS
from app.system.status import sam2_problem, teacher_problem
from weldpool_core.heatmap import HeatmapParams

if TYPE_CHECKING:
    from fastapi.templating import Jinja2Templates

router = APIRouter(include_in_schema=False)


def _safe_next(target: str | None) -> str:
    """Only same-site paths: never redirect a login to another host."""
    if not target or not target.startswith("/") or target.startswith("//") or "\\" in target:
        return "/"
    return target


@cache
def templates() -> Jinja2Templates:
    """The pages' Jinja environment, made with the first page (an API process never needs it)."""
    from fastapi.templating import Jinja2Templates

    return Jinja2Templates(directory=Path(__file__).resolve().parents[2] / "templates")


HELP_TOPICS = {
    "frames": "/help/guides/ingest",
    "review": "/help/guides/reviewing",
    "jobs": "/help/operations/deploy#jobs-and-workers",
    "models": "/help/guides/student",
    "metrics": "/help/guides/student#the-models-and-metrics-pages",
    "live": "/help/guides/live#the-live-view",
    "process": "/help/guides/process",
    "users": "/help/guides/team#users",
    "label-config": "/help/guides/label-config",
    "account": "/help/operations/security",
    "tokens": "/help/operations/security",
}
"""The manual's page for each page of the app: the header's Help opens it (/help: the start)."""


def render(request: Request, name: str, status_code: int = 200, **context: Any) -> HTMLResponse:
    """A page with the logged-in user and their CSRF token in its context."""
    web_session = getattr(request.state, "web_session", None)
    context.setdefault("user", web_session.user if web_session else None)
    context.setdefault("may", ",".join(allowed(web_session.user.role)) if web_session else "")
    context.setdefault("csrf_token", web_session.csrf_token if web_session else "")
    context.setdefault("review_stage", request.app.state.settings.review_stage)
    context.setdefault("help_url", HELP_TOPICS.get(context.get("page", ""), "/help/"))
    if web_session is not None:
        admin = may(web_session.user, Action.administer)
        settings = request.app.state.settings
        context.setdefault("teacher_problem", teacher_problem(settings, admin=admin))
        context.setdefault("sam2_problem", sam2_problem(settings, admin=admin))
    return templates().TemplateResponse(request, name, context, status_code=status_code)


def _login_page(
    request: Request, next_url: str, error: str = "", status_code: int = 200, username: str = ""
) -> Response:
    """The login form; after a refusal it keeps the name typed (only the password is retyped)."""
    token = new_csrf_token()
    response = render(
        request,
        "login.html",
        status_code,
        next=next_url,
        error=error,
        login_csrf=token,
        username=username[:64],
    )
    response.set_cookie(LOGIN_CSRF_COOKIE, token, httponly=True, samesite="strict", path="/login")
    return response


@router.get("/login")
def login_form(
    request: Request, user: Annotated[User | None, Depends(optional_user)], next: str = "/"
) -> Response:
    if user is not None:
        return RedirectResponse(_safe_next(next), status_code=303)
    return _login_page(request, _safe_next(next))


@router.post("/login")
def login(
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    username: Annotated[str, Form()] = "",
    password: Annotated[str, Form()] = "",
    csrf_token: Annotated[str, Form()] = "",
    next: Annotated[str, Form()] = "/",
) -> Response:
    expected = request.cookies.get(LOGIN_CSRF_COOKIE, "")
    if not expected or not constant_time_equal(expected, csrf_token):
        return _login_page(request, _safe_next(next), "The form expired; please log in again.", 403)
    try:
        user = authenticate_throttled(request, session, username, password)
    except TooManyAttemptsError as exc:
        response = _login_page(request, _safe_next(next), exc.message, 429, username)
        response.headers["Retry-After"] = str(math.ceil(exc.retry_after))
        return response
    except AuthenticationError as exc:
        return _login_page(request, _safe_next(next), exc.message, 401, username)
    _, cookie = open_web_session(session, user, settings.session_ttl_hours)
    user.last_login_at = utcnow()
    session.commit()
    response = RedirectResponse(_safe_next(next), status_code=303)
    response.set_cookie(
        SESSION_COOKIE,
        cookie,
        httponly=True,
        samesite="lax",
        secure=settings.cookie_secure,
        max_age=int(settings.session_ttl_hours * 3600),
    )
    response.delete_cookie(LOGIN_CSRF_COOKIE, path="/login")
    return response


@router.post("/logout")
def logout(
    request: Request,
    session: SessionDep,
    _user: Annotated[User, Depends(current_user)],
) -> Response:
    # current_user has checked the form's csrf_token against the session.
    close_web_session(session, request.cookies.get(SESSION_COOKIE, ""))
    session.commit()
    response = RedirectResponse("/login", status_code=303)
    response.delete_cookie(SESSION_COOKIE)
    return response


LoggedIn = Annotated[User, Depends(current_user)]


@router.get("/")
def home(request: Request, _user: LoggedIn) -> Response:
    """Sequences, frames (the review queue by default) and uploads."""
    return render(request, "home.html", page="frames")


@router.get("/frames/{frame_id}")
def review(request: Request, frame_id: IdPath, _user: LoggedIn) -> Response:
    """Review one frame: mask, keypoints, click corrections, verdict; validation keypoints."""
    keypoints = HeatmapParams().k  # Algorithm 1's k: the validation set places as many
    return render(
        request,
        "review.html",
        page="review",
        frame_id=frame_id,
        keypoints=keypoints,
        page_keys=REVIEW_KEYS,
    )


@router.get("/sequences/{sequence_id}")
def timeline(request: Request, sequence_id: IdPath, _user: LoggedIn) -> Response:
    """A weld run over time: its frames as a strip, the pool geometry curves, propagation."""
    return render(request, "timeline.html", page="frames", sequence_id=sequence_id)


@router.get("/process")
def process(request: Request, _user: LoggedIn) -> Response:
    """The process map: runs against their process parameters, with the law through them."""
    return render(request, "process.html", page="process")


@router.get("/jobs")
def jobs(request: Request, _user: LoggedIn) -> Response:
    """Background jobs with live progress."""
    from app.jobs.registry import job_kinds

    return render(request, "jobs.html", page="jobs", kinds=job_kinds())


@router.get("/tokens")
def tokens(request: Request, _user: LoggedIn) -> Response:
    """The caller's API tokens: create (shown once), list, revoke."""
    return render(request, "tokens.html", page="tokens")


@router.get("/account")
def account(request: Request, _user: LoggedIn) -> Response:
    """One's own account: change the password, one's API tokens."""
    return render(request, "account.html", page="account")


@router.get("/label-config")
def label_config(request: Request, user: LoggedIn) -> Response:
    """The instance's classes, attributes and frame tags (admins)."""
    if not may(user, Action.administer):
        return render(
            request, "forbidden.html", 403, page="label-config", what="configure the classes"
        )
    return render(request, "label_config.html", page="label-config")


@router.get("/users")
def users(request: Request, user: LoggedIn) -> Response:
    """The lab's users (admins): add, change role, deactivate, set a new password."""
    if not may(user, Action.administer):
        return render(request, "forbidden.html", 403, page="users", what="manage users")
    return render(request, "users.html", page="users")


@router.get("/models")
def models(request: Request, _user: LoggedIn) -> Response:
    """Student model versions: metrics, training curves, promotion, training."""
    return render(request, "models.html", page="models")


@router.get("/live")
def live(request: Request, _user: LoggedIn) -> Response:
    """A student live on a camera, stream or video: the frame with mask and keypoints, the
    geometry scrolling, fps and latency."""
    return render(request, "live.html", page="live")


@router.get("/metrics")
def metrics(request: Request, _user: LoggedIn) -> Response:
    """The loop's quality: the student's learning curve, the teacher against reviewed masks,
    the reviewers' acceptance of teacher proposals."""
    return render(request, "metrics.html", page="metrics")
