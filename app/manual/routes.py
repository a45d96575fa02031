"""/help, the manual, and /docs, the API's Swagger UI: for logged-in users (as every page but
the login page)."""

from __future__ import annotations

from pathlib import PurePosixPath
from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response

from app.core.models import User
from app.core.security import current_user
from app.manual.pages import IMAGE_TYPES, nav, picture, render_page
from app.web.routes import render

router = APIRouter(include_in_schema=False)
LoggedIn = Annotated[User, Depends(current_user)]


@router.get("/help")
@router.get("/help/{path:path}")
def help_page(request: Request, _user: LoggedIn, path: str = "") -> Response:
    """A page of the manual (docs/), or a picture it shows."""
    if PurePosixPath(path).suffix.lower() in IMAGE_TYPES:
        content, media_type = picture(path)
        return Response(content, media_type=media_type, headers={"Cache-Control": "max-age=300"})
    page = render_page(path, request.app.openapi)
    return render(request, "help.html", page="help", manual=page, nav=nav())


@router.get("/docs")
def api_docs(request: Request, _user: LoggedIn) -> Response:
    """Swagger UI from the vendored copy under static/ (works offline); "Try it out" sends the
    session's CSRF token, or the token given under Authorize."""
    return render(request, "docs.html")
