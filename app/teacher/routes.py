"""The teacher's endpoints: teacher runs, a frame's embedding warmed before its first click, a
run's embeddings computed ahead, and the embedding cache."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, status
from pydantic import BaseModel

from app.core.bounds import IdPath
from app.core.deps import QueueDep, SessionDep, SettingsDep, StorageDep
from app.core.models import get_frame
from app.core.security import AdminUser, CurrentUser
from app.frames.listing import run_scope
from app.frames.sequences import get_sequence
from app.jobs.schemas import JobCreated
from app.jobs.service import create_job
from app.teacher import runtime, warm
from app.teacher.schemas import EmbeddingOut, TeacherRunIn

router = APIRouter(tags=["teacher"])


@router.post("/teacher/runs", response_model=JobCreated, status_code=status.HTTP_202_ACCEPTED)
def start_teacher_run(
    body: TeacherRunIn, session: SessionDep, queue: QueueDep, user: CurrentUser
) -> JobCreated:
    """The teacher proposes a mask, heatmap and keypoints for each frame, in a worker job."""
    scope, listed = run_scope(session, body.frame_ids, body.sequence_id)
    params: dict[str, Any] = {"prompts": body.prompts, "force": body.force} | scope
    job = create_job(session, queue, "teacher", params, user, frame_ids=listed)
    return JobCreated(job_id=job.id)


class EmbeddingCacheOut(BaseModel):
    files: int
    bytes: int
    limit_bytes: int


class EmbeddingCacheCleared(BaseModel):
    removed_files: int
    removed_bytes: int


@router.get("/system/embedding-cache", response_model=EmbeddingCacheOut, tags=["system"])
def embedding_cache(settings: SettingsDep, _user: CurrentUser) -> EmbeddingCacheOut:
    """The SAM2 embeddings cached on disk for clicks and propagation, and the size limit
    (`WELDPOOL_EMBEDDING_CACHE_MB`; least recently used out)."""
    files, size = runtime.embedding_cache_usage(settings)
    return EmbeddingCacheOut(
        files=files, bytes=size, limit_bytes=runtime.embedding_cache_limit(settings)
    )


@router.delete("/system/embedding-cache", response_model=EmbeddingCacheCleared, tags=["system"])
def clear_embedding_cache(settings: SettingsDep, _admin: AdminUser) -> EmbeddingCacheCleared:
    """Empty the embedding cache (admins): the next click on each frame computes it again."""
    files, size = runtime.clear_embedding_cache(settings)
    return EmbeddingCacheCleared(removed_files=files, removed_bytes=size)


@router.post("/frames/{frame_id}/embedding", response_model=EmbeddingOut)
def warm_embedding(
    frame_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    _user: CurrentUser,
) -> EmbeddingOut:
    """Start computing the frame's SAM2 embedding in this web process (the review page asks
    when it opens, then for the next frames of its queue), so its first click is as fast as
    the later ones; at most a few at once (`busy`: ask again)."""
    frame = get_frame(session, frame_id)
    return EmbeddingOut(**vars(warm.warmth(storage, settings, frame, start=True)))


@router.get("/frames/{frame_id}/embedding", response_model=EmbeddingOut)
def embedding_state(
    frame_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    _user: CurrentUser,
) -> EmbeddingOut:
    """Where the frame's embedding stands (nothing is started)."""
    frame = get_frame(session, frame_id)
    return EmbeddingOut(**vars(warm.warmth(storage, settings, frame, start=False)))


@router.post(
    "/sequences/{sequence_id}/embeddings",
    response_model=JobCreated,
    status_code=status.HTTP_202_ACCEPTED,
)
def precompute_embeddings(
    sequence_id: IdPath, session: SessionDep, queue: QueueDep, user: CurrentUser
) -> JobCreated:
    """Compute SAM2's embedding of every frame of the run ahead of review (a job): the first
    click on any frame is then as fast as the later ones."""
    get_sequence(session, sequence_id)
    job = create_job(session, queue, "embed", {"sequence_id": sequence_id}, user)
    return JobCreated(job_id=job.id)
