"""/api/v1/jobs: read job state, cancel, and start a diagnostic job."""

from __future__ import annotations

from fastapi import APIRouter, Query, status

from app.core.bounds import IdPath, OffsetQuery
from app.core.deps import QueueDep, SessionDep
from app.core.models import JobStatus
from app.core.security import AdminUser, CurrentUser
from app.jobs import service
from app.jobs.registry import lane_of
from app.jobs.schemas import DiagnosticJobIn, JobCreated, JobOut, JobPage

router = APIRouter(prefix="/jobs", tags=["jobs"])


@router.get("", response_model=JobPage)
def list_jobs(
    session: SessionDep,
    _user: CurrentUser,
    kind: str | None = None,
    status: JobStatus | None = None,
    limit: int = Query(50, ge=1, le=500),
    offset: OffsetQuery = 0,
) -> JobPage:
    """Recent jobs, newest first."""
    rows, total = service.list_jobs(session, kind, status, limit, offset)
    return JobPage(items=_out(session, rows), total=total)


def _out(session: SessionDep, jobs: list) -> list[JobOut]:
    """Jobs as clients see them, with their lane and what a queued one waits behind."""
    waiting = service.waiting_for(session, jobs)
    return [
        JobOut.model_validate(job).model_copy(
            update={"lane": lane_of(job.kind), "waiting": waiting.get(job.id)}
        )
        for job in jobs
    ]


@router.get("/{job_id}", response_model=JobOut)
def get_job(job_id: IdPath, session: SessionDep, _user: CurrentUser) -> JobOut:
    """One job's status, progress, result or error."""
    return _out(session, [service.get_job(session, job_id)])[0]


@router.post("/{job_id}/cancel", response_model=JobOut)
def cancel_job(job_id: IdPath, session: SessionDep, user: CurrentUser) -> JobOut:
    """Cancel a queued job, or ask a running one to stop (its starter, a reviewer or an admin)."""
    return JobOut.model_validate(service.cancel_job(session, job_id, user))


@router.post("/diagnostic", response_model=JobCreated, status_code=status.HTTP_202_ACCEPTED)
def start_diagnostic(
    body: DiagnosticJobIn, session: SessionDep, queue: QueueDep, user: AdminUser
) -> JobCreated:
    """Start a job that waits with progress (and fails on request): checks that workers run."""
    job = service.create_job(session, queue, "diagnostic", body.model_dump(), user)
    return JobCreated(job_id=job.id)
