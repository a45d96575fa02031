"""/api/v1/health: is the service usable, and what is missing."""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from app.core.db import schema_revision
from app.jobs.queue import describe
from app.jobs.registry import LANES, kinds_in
from app.jobs.runner import unserved_kinds, worker_rows
from app.system.status import teacher_problem
from weldpool_core.teacher.weights import weights_status

router = APIRouter(tags=["system"])


def _database(request: Request) -> dict[str, Any]:
    engine = request.app.state.engine
    try:
        current, head = schema_revision(engine)
    except sa.exc.SQLAlchemyError as exc:
        return {
            "status": "error",
            "backend": engine.dialect.name,
            "detail": str(exc).splitlines()[0],
        }
    state = "ok" if current == head else "error"
    return {"status": state, "backend": engine.dialect.name, "revision": current, "head": head}


def _workers(request: Request) -> dict[str, Any]:
    """Live workers with their lanes and what each cannot run, and the job kinds that no
    live worker can run (``unserved``)."""
    try:
        workers = worker_rows(
            request.app.state.session_factory, request.app.state.settings.job_stale_after_s
        )
    except sa.exc.SQLAlchemyError:
        return {"alive": None}
    return {
        "alive": len(workers),
        "workers": [
            {  # no host name: /health answers anyone
                "threads": worker.threads,
                "lanes": worker.lanes.split(","),
                "unable": worker.unable or {},
            }
            for worker in workers
        ],
        "unserved": unserved_kinds(workers, kinds_in(LANES)),
    }


@router.get("/health")
def health(request: Request) -> JSONResponse:
    """Database, queue, workers, the file store and teacher weights; 200 when the service can
    work, else 503 (the store's check waits a request's bound and is kept a few seconds).

    With no live worker, or without the teacher's weights, the API still works (200) but
    ``status`` is ``degraded`` and ``warnings`` says what will not work and how to fix it.
    """
    settings = request.app.state.settings
    database = _database(request)
    queue = describe(request.app.state.queue) | _workers(request)
    teacher = {
        "dino": weights_status(settings.dino, "WELDPOOL_DINO").public(),
        "sam2": weights_status(settings.sam2, "WELDPOOL_SAM2").public(),
    }
    storage = request.app.state.store_check()
    ok = database["status"] == "ok" and queue["status"] == "ok" and storage["status"] == "ok"
    warnings = []
    problem = teacher_problem(settings)
    if problem:
        warnings.append(problem)
    by_reason: dict[str, list[str]] = {}
    for kind, reason in sorted(queue.get("unserved", {}).items()):
        by_reason.setdefault(reason, []).append(kind)
    for reason, kinds in by_reason.items():
        if not (problem and "weights are missing" in reason):  # said once, above
            warnings.append(f"No live worker can run {' or '.join(kinds)} jobs: {reason}")
    if queue.get("alive") == 0:
        warnings.append(
            "No worker is alive: jobs wait in the queue until `weldpool worker` (or `weldpool "
            "serve` without --no-worker) runs."
        )
    body = {
        "status": ("ok" if not warnings else "degraded") if ok else "error",
        "warnings": warnings,
        "database": database,
        "queue": queue,
        "storage": storage,
        "teacher": teacher,
    }
    return JSONResponse(body, status_code=200 if ok else 503)
