"""/api/v1/jobs: read job state, cancel, and start a diagnostic job."""

from __future__ import annotations

from fastapi import APIRouter, Query, status

from app.bounds import IdPath, OffsetQuery
from app.deps import QueueDep, SessionDep
from app.jobs import service
from app.jobs.schemas import DiagnosticJobIn, JobCreated, JobOut, JobPage
from app.models import JobStatus
from app.security import AdminUser, CurrentUser

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
    return JobPage(items=[JobOut.model_validate(r) for r in rows], total=total)


@router.get("/{job_id}", response_model=JobOut)
def get_job(job_id: IdPath, session: SessionDep, _user: CurrentUser) -> JobOut:
    """One job's status, progress, result or error."""
    return JobOut.model_validate(service.get_job(session, job_id))


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
