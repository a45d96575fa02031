"""The app factory: REST API under /api/v1, browser pages, static files, embedded worker."""

from __future__ import annotations

import math
import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import sqlalchemy as sa
import structlog
from fastapi import Depends, FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles
from sqlalchemy.orm.exc import ObjectDeletedError, StaleDataError
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.core.config import Settings, get_settings
from app.core.db import create_db_engine, create_session_factory
from app.core.errors import (
    AuthenticationError,
    TooManyAttemptsError,
    WeldpoolError,
    http_status_of,
    without_server_paths,
)
from app.core.headers import SecurityHeaders
from app.core.housekeeping import FileCollector
from app.core.limits import BodySizeLimit
from app.core.openapi import openapi_schema
from app.core.processes import stop_processes
from app.core.security import (
    SESSION_COOKIE,
    LoginThrottle,
    current_user,
    web_session_for_cookie,
)
from app.frames.routes import router as frames_router
from app.imports.routes import router as imports_router
from app.jobs.queue import EmbeddedWorker, JobQueue, JobReaper
from app.jobs.registry import load_job_handlers
from app.jobs.routes import router as jobs_router
from app.labelconfig.routes import router as label_config_router
from app.live.routes import router as live_router
from app.live.service import LiveViews
from app.manual.routes import router as manual_router
from app.metrics.routes import router as metrics_router
from app.process.routes import router as process_router
from app.proposals import policy
from app.proposals.routes import router as proposals_router
from app.review.agreement_routes import router as agreement_router
from app.review.routes import router as review_router
from app.storage import open_storage
from app.system.routes import router as system_router
from app.system.status import StoreCheck
from app.teacher.routes import router as teacher_router
from app.timeline.routes import router as timeline_router
from app.training.routes import router as training_router
from app.users.routes import router as users_router
from app.users.routes import tokens_router
from app.web.routes import render
from app.web.routes import router as web_router

ROOT = Path(__file__).resolve().parent.parent
log = structlog.get_logger(__name__)


def _where(loc: Any) -> str:
    """A field's place as a client names it: without the request part and pydantic's tags for
    the members of a union (``str-enum[FrameStatus]``, ``literal['all']``)."""
    return ".".join(str(p) for p in loc if p not in ("body", "query", "path") and "[" not in str(p))


def _validation_sentence(exc: RequestValidationError) -> str:
    errors = exc.errors()
    first = errors[0]
    if first.get("type") == "json_invalid":
        return "The request body is not valid JSON."
    where = _where(first.get("loc", ()))
    # A value none of a union's choices takes: all of them in one list.
    choices = [
        value
        for e in errors
        if _where(e.get("loc", ())) == where and e.get("type") in ("enum", "literal_error")
        for value in re.findall(r"'([^']*)'", str(e.get("ctx", {}).get("expected", "")))
    ]
    if len(errors) > 1 and choices:
        message = f"Input should be one of {', '.join(choices)}"
    else:
        message = str(first.get("msg", "is invalid")).removeprefix("Value error, ").rstrip(".")
    return f"{where or 'The request'}: {message}."


_PAGE_TITLES = {404: "Not found", 422: "Not a valid address"}


def _browser_page(request: Request) -> bool:
    """Whether a person's browser asked for a page (not the API, not a script)."""
    return (
        request.method == "GET"
        and "text/html" in request.headers.get("accept", "")
        and not request.url.path.startswith("/api/")
    )


async def _error_page(request: Request, status: int, message: str) -> Response:
    """The error as a page with a way back (a browser was shown the API's JSON); its header
    shows who is logged in, read from the cookie when no route did (off the event loop; a
    database that does not answer leaves the header out, not the page)."""
    title = _PAGE_TITLES.get(status, "Not possible" if status < 500 else "Not available")
    cookie = request.cookies.get(SESSION_COOKIE)

    def page() -> Response:
        return render(request, "error.html", status, title=title, message=message)

    def page_of_session() -> Response:
        with request.app.state.session_factory() as session:
            request.state.web_session = web_session_for_cookie(session, cookie or "")
            return page()

    if getattr(request.state, "web_session", None) is not None or not cookie:
        return page()
    try:
        return await run_in_threadpool(page_of_session)
    except Exception:
        log.warning("error_page.no_session", path=request.url.path, exc_info=True)
        request.state.web_session = None
        return page()


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Response:
        if _browser_page(request) and exc.status_code == 404:
            return await _error_page(request, 404, f"There is no page at {request.url.path}.")
        return JSONResponse(
            {"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers
        )

    @app.exception_handler(WeldpoolError)
    async def weldpool_error(request: Request, exc: WeldpoolError) -> Response:
        status = http_status_of(exc)
        if isinstance(exc, AuthenticationError) and _browser_page(request):
            return RedirectResponse(f"/login?next={request.url.path}", status_code=303)
        headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
        if isinstance(exc, TooManyAttemptsError):
            headers = {"Retry-After": str(math.ceil(exc.retry_after))}
        detail = without_server_paths(exc.message, request.app.state.settings.home)
        if _browser_page(request):
            return await _error_page(request, status, detail)
        body = {"detail": detail} | getattr(exc, "extra", {})
        return JSONResponse(body, status_code=status, headers=headers)

    @app.exception_handler(StaleDataError)
    @app.exception_handler(ObjectDeletedError)
    async def changed_meanwhile(request: Request, exc: Exception) -> Response:
        log.info("request.raced", path=request.url.path, error=str(exc))
        return JSONResponse(
            {
                "detail": "What this request worked on was changed or deleted by someone else "
                "meanwhile; reload and try again."
            },
            status_code=409,
        )

    if app.state.settings.storage_url:
        from botocore.exceptions import BotoCoreError, ClientError

        @app.exception_handler(BotoCoreError)
        @app.exception_handler(ClientError)
        async def storage_error(request: Request, exc: Exception) -> Response:
            log.warning("storage.unavailable", path=request.url.path, error=str(exc))
            return JSONResponse(
                {"detail": "The object store did not answer as expected; try again shortly."},
                status_code=503,
                headers={"Retry-After": "5"},
            )

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> Response:
        if _browser_page(request):
            sentence = _validation_sentence(exc)  # "frame_id: Input should be …"
            return await _error_page(request, 422, f"This address is not valid: {sentence}")
        errors = [{"loc": list(e.get("loc", ())), "msg": e.get("msg", "")} for e in exc.errors()]
        return JSONResponse(
            {"detail": _validation_sentence(exc), "errors": errors}, status_code=422
        )

    @app.exception_handler(sa.exc.DataError)
    async def data_error(request: Request, exc: sa.exc.DataError) -> Response:
        # A value the schemas let through but the database cannot hold: the client's mistake.
        log.warning("request.data_error", path=request.url.path, error=str(exc.orig)[:200])
        return JSONResponse(
            {
                "detail": "A value in the request is out of range or not storable (e.g. a NUL "
                "character); check the numbers and text you sent."
            },
            status_code=400,
        )

    @app.exception_handler(Exception)
    async def unexpected(request: Request, exc: Exception) -> Response:
        log.exception("request.crashed", path=request.url.path)
        return JSONResponse(
            {"detail": "Internal error; the server log has the details."}, status_code=500
        )


def _install_state(
    app: FastAPI, settings: Settings, engine: sa.engine.Engine, queue: JobQueue
) -> None:
    """What the routes find on ``app.state`` (the store's calls wait a request's bounds)."""
    app.state.settings = settings
    app.state.engine = engine
    app.state.session_factory = queue.session_factory
    app.state.queue = queue
    app.state.storage = open_storage(settings, for_requests=True)
    app.state.store_check = StoreCheck(app.state.storage)
    app.state.live_views = LiveViews()
    app.state.login_throttle = LoginThrottle(
        settings.login_max_failures, settings.login_lockout_minutes * 60
    )


def create_app(settings: Settings | None = None, *, embedded_worker: bool = False) -> FastAPI:
    """Build the service; with ``embedded_worker`` it also runs jobs in this process."""
    settings = settings or get_settings()
    settings.ensure_home()
    load_job_handlers()
    engine = create_db_engine(settings.resolved_database_url)
    session_factory = create_session_factory(engine)
    policy.watch(session_factory, open_storage(settings))
    queue = JobQueue(settings, session_factory)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # The embedded worker reaps lost jobs itself; without it, a reaper thread does.
        background = (
            EmbeddedWorker(queue, settings.workers) if embedded_worker else JobReaper(queue)
        )
        collector = FileCollector(session_factory, app.state.storage)
        background.start()
        collector.start()
        try:
            yield
        finally:
            collector.stop()
            background.stop()
            app.state.live_views.stop_all()
            stop_processes()
            queue.close()
            engine.dispose()

    app = FastAPI(
        title="weldpool",
        summary="Learn the shape of a molten weld pool from camera frames.",
        version="0.1.0",
        docs_url=None,
        redoc_url=None,
        openapi_url=None,
        lifespan=lifespan,
    )
    _install_state(app, settings, engine, queue)
    app.add_middleware(BodySizeLimit, max_bytes=int(settings.max_request_mb * 2**20))
    app.add_middleware(SecurityHeaders)
    _install_error_handlers(app)

    # Each router straight into the app under /api/v1: FastAPI builds an included router's
    # routes on its first request, but a router nested without a prefix (an /api/v1 router
    # holding them all) has every route built again when it is included.
    api = "/api/v1"
    protected = [Depends(current_user)]
    app.include_router(system_router, prefix=api)
    app.include_router(users_router, prefix=api, dependencies=protected)
    app.include_router(tokens_router, prefix=api)  # a token by password, or for the caller
    app.include_router(jobs_router, prefix=api, dependencies=protected)
    app.include_router(frames_router, prefix=api, dependencies=protected)
    app.include_router(proposals_router, prefix=api, dependencies=protected)
    app.include_router(teacher_router, prefix=api, dependencies=protected)
    app.include_router(review_router, prefix=api, dependencies=protected)
    app.include_router(agreement_router, prefix=api, dependencies=protected)
    app.include_router(label_config_router, prefix=api, dependencies=protected)
    app.include_router(imports_router, prefix=api, dependencies=protected)
    app.include_router(training_router, prefix=api, dependencies=protected)
    app.include_router(metrics_router, prefix=api, dependencies=protected)
    app.include_router(process_router, prefix=api, dependencies=protected)
    app.include_router(timeline_router, prefix=api, dependencies=protected)
    app.include_router(live_router, prefix=api, dependencies=protected)
    app.include_router(web_router)
    app.include_router(manual_router)

    app.openapi = lambda: openapi_schema(app)  # type: ignore[method-assign]

    @app.get("/api/v1/openapi.json", include_in_schema=False, dependencies=protected)
    def openapi() -> JSONResponse:
        return JSONResponse(app.openapi())

    app.mount("/static", StaticFiles(directory=ROOT / "static"), name="static")
    return app
