"""Background work of the teacher: teacher runs (DINO → prompts → SAM2 → Algorithm 1 per frame)
and embedding runs, both shared in chunks by every worker they reach."""

from __future__ import annotations

import functools
from typing import Any

import sqlalchemy as sa
import structlog

from app.core.errors import failure_sentence, store_outage, without_server_paths
from app.core.frame_rows import FrameDeleted, frame_exists
from app.core.models import Frame
from app.frames.listing import run_frames, scope_frames
from app.jobs.fanout import Fanout
from app.jobs.registry import (
    JobCancelled,
    JobContext,
    JobInterrupted,
    JobLost,
    counted,
    job_handler,
)
from app.proposals.record import claim, has_proposal, record_teacher_proposal, release
from app.storage import Storage, open_storage
from app.storage.pixels import frame_rgb
from app.teacher import runtime
from weldpool_core.errors import WeldpoolError
from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS

log = structlog.get_logger(__name__)


TEACHER_CHUNK = 4
"""Frames per chunk of a teacher run that several workers share (about 16 s of CPU each)."""


@job_handler("teacher", max_attempts=2, fanout=True)
def teacher_run(ctx: JobContext) -> dict[str, Any]:
    """DINO → prompts → SAM2 → Algorithm 1 for each frame, one proposal per frame, in chunks
    that every worker the run reaches shares (``app.jobs.fanout``); frames the same teacher
    already saw are skipped, so a lost run is simply re-run."""
    prompts = ctx.params.get("prompts", DEFAULT_PROMPTS)
    force = bool(ctx.params.get("force", False))
    ctx.progress(0.0, "loading the teacher")
    teacher = runtime.teacher(ctx.settings, prompts)  # missing weights: the job fails here
    ctx.check_cancelled()
    storage = open_storage(ctx.settings)
    fan = Fanout(ctx, TEACHER_CHUNK)
    if not ctx.helper:
        fan.plan(functools.partial(_teacher_frames, ctx))
        fan.invite()
    for index in fan.chunks():
        with fan.working(index) as result:
            result.update(_teacher_chunk(ctx, storage, teacher, fan.items(index), force))
        ctx.progress(fan.progress(), fan.message())
    if ctx.helper:
        return {}
    results = fan.results()
    proposed = sum(r["proposed"] for r in results)
    skipped = sum(r["skipped"] for r in results)
    failed = [f for r in results for f in r["failed"]]
    deleted = [d for r in results for d in r["deleted"]]
    if len(deleted) == fan.size:
        raise WeldpoolError("Every frame of this run was deleted before the teacher saw it.")
    if failed and not proposed and not skipped and len(failed) + len(deleted) == fan.size:
        raise WeldpoolError(f"The teacher failed on every frame; the first: {failed[0]['error']}")
    ctx.summary = teacher_summary(proposed, skipped, failed, len(deleted))
    if (shared := runtime.shared_embeddings(ctx.settings)) is not None:
        shared.prune(ctx.settings.shared_embeddings_days)
    return {
        "proposed": proposed,
        "skipped": skipped,
        "failed": failed,
        "deleted_frame_ids": deleted,
        "model_id": teacher.model_id,
        "workers": len(fan.workers()),
    }


def _teacher_frames(ctx: JobContext) -> list[int]:
    """The run's frames, read when it starts (``app.frames.listing.scope_frames``)."""
    with ctx.session_factory() as session:
        return scope_frames(session, ctx.job_id, ctx.params)


def _teacher_chunk(
    ctx: JobContext, storage: Storage, teacher: Any, frame_ids: list[int], force: bool
) -> dict[str, Any]:
    """The teacher on one chunk's frames: what it proposed, skipped, failed and found deleted.
    Each frame it works is claimed first (two runs of this teacher propose it once); on a GPU
    worker the claimed frames go through DINO and SAM2's encoder in one batch."""
    proposed, skipped, failed, deleted = 0, 0, [], []
    claimed: list[int] = []
    for frame_id in frame_ids:
        with ctx.session_factory() as session:
            if session.get(Frame, frame_id) is None:
                deleted.append(frame_id)
            elif not force and has_proposal(session, frame_id, teacher.model_id):
                skipped += 1
            elif not claim(ctx.session_factory, frame_id, teacher.model_id, ctx.job_id):
                skipped += 1  # another run of this teacher is proposing it now
            else:
                claimed.append(frame_id)
    try:
        ahead = _batched(ctx, storage, teacher, claimed)
        for frame_id in claimed:
            with ctx.session_factory() as session:
                frame = session.get(Frame, frame_id)
                if frame is None:
                    outcome: str | FrameDeleted | None = FrameDeleted(frame_id)
                elif not force and has_proposal(session, frame_id, teacher.model_id):
                    outcome = "seen"  # a run that recorded it since this one looked
                else:
                    outcome = _propose(ctx, session, storage, teacher, frame, ahead.get(frame_id))
            release(ctx.session_factory, frame_id, teacher.model_id, ctx.job_id)
            if outcome == "seen":
                skipped += 1
            elif outcome is None:
                proposed += 1
            elif isinstance(outcome, FrameDeleted):
                deleted.append(frame_id)
            else:
                failed.append({"frame_id": frame_id, "error": outcome})
            ctx.check_cancelled()
    finally:
        for frame_id in claimed:  # a stopped chunk leaves no claim behind
            release(ctx.session_factory, frame_id, teacher.model_id, ctx.job_id)
    return {"proposed": proposed, "skipped": skipped, "failed": failed, "deleted": deleted}


def _batched(
    ctx: JobContext, storage: Storage, teacher: Any, frame_ids: list[int]
) -> dict[int, Any]:
    """The teacher's results for ``frame_ids`` from batches of ``runtime.teacher_batch``
    frames (``Teacher.run_many``); empty on the CPU (one frame at a time is as fast there).
    A frame that cannot be read, or a batch that fails, is left to ``_propose``, which works
    it alone and says why it failed."""
    size = runtime.teacher_batch(ctx.settings, teacher)
    results: dict[int, Any] = {}
    if size < 2 or len(frame_ids) < 2:
        return results
    for start in range(0, len(frame_ids), size):
        readable: list[tuple[int, Any, str]] = []
        with ctx.session_factory() as session:
            for frame_id in frame_ids[start : start + size]:
                frame = session.get(Frame, frame_id)
                try:
                    if frame is not None:
                        readable.append((frame_id, frame_rgb(storage, frame), frame.sha256))
                except Exception as exc:  # ``_propose`` reads it again and says why
                    if store_outage(exc):
                        raise
        if len(readable) < 2:
            continue
        try:
            batch = teacher.run_many(
                [image for _, image, _ in readable],
                [sha for _, _, sha in readable],
                between=ctx.check_cancelled,
            )
        except (JobCancelled, JobInterrupted, JobLost):
            raise
        except Exception:
            log.warning("teacher.batch_failed", frames=[i for i, _, _ in readable], exc_info=True)
            continue
        results.update(
            {frame_id: result for (frame_id, _, _), result in zip(readable, batch, strict=True)}
        )
    return results


def _propose(
    ctx: JobContext,
    session: Any,
    storage: Storage,
    teacher: Any,
    frame: Frame,
    ahead: Any = None,
) -> str | FrameDeleted | None:
    """The teacher on one frame (or its result ``ahead`` from a batch), recorded: None when it
    was, the frame's failure in one sentence (stored on the frame), or FrameDeleted when the
    frame went meanwhile."""
    frame_id = frame.id  # a rollback expires the object; a deleted row cannot be read again
    try:
        result = ahead or teacher.run(
            frame_rgb(storage, frame), frame.sha256, between=ctx.check_cancelled
        )
        ctx.check_cancelled()  # a lost or cancelled attempt records nothing more
        record_teacher_proposal(
            session,
            storage,
            frame,
            result,
            teacher.model_id,
            ctx.job_id,
            ctx.settings.uncertainty_weights,
        )
    except (JobCancelled, JobInterrupted, JobLost):
        raise
    except FrameDeleted as exc:
        return exc
    except Exception as exc:  # one bad frame must not end the run for the others
        session.rollback()
        if store_outage(exc):
            raise  # the store, not the frame: the job pauses and runs again
        if not frame_exists(session, frame_id):  # its file went with it
            return FrameDeleted(frame_id)
        message = without_server_paths(failure_sentence(exc), ctx.settings.home)
        session.execute(
            sa.update(Frame).where(Frame.id == frame_id).values(teacher_error=message[:500])
        )
        session.commit()
        log.warning(
            "teacher.frame_failed",
            frame_id=frame_id,
            error=message,
            exc_info=not isinstance(exc, WeldpoolError | OSError),
        )
        return message
    return None


def teacher_summary(
    proposed: int, skipped: int, failed: list[dict[str, Any]], deleted: int = 0
) -> str:
    """The teacher job's last word: what it proposed, skipped and could not do (the first
    failure's reason; the rest are on their frames)."""
    parts = [f"{counted(proposed, 'frame')} proposed"]
    if skipped:
        parts.append(
            f"{skipped} skipped (this teacher proposed them before; run with force to redo)"
        )
    if deleted:
        parts.append(f"{deleted} skipped (deleted while the teacher ran)")
    if failed:
        parts.append(f"{len(failed)} failed, the first: {failed[0]['error']}")
    return "; ".join(parts)


EMBED_CHUNK = 8
"""Frames per chunk of an embedding run that several workers share."""


@job_handler("embed", max_attempts=2, fanout=True)
def embed_run(ctx: JobContext) -> dict[str, Any]:
    """SAM2's image embedding of every frame of a weld run, into the embedding cache (shared
    through the object store when there is one), in chunks every worker the run reaches shares:
    the first click on any of its frames is then as fast as the later ones, and propagation and
    the teacher reuse them."""
    from weldpool_core.teacher.cache import cached_embedding

    storage = open_storage(ctx.settings)
    ctx.progress(0.0, "loading SAM2")
    predictor = runtime.sam2_predictor(ctx.settings)
    cache = runtime.embedding_cache(ctx.settings)
    with ctx.session_factory() as session:
        frames = {f.id: f for f in run_frames(session, int(ctx.params["sequence_id"]))}
    fan = Fanout(ctx, EMBED_CHUNK)
    if not ctx.helper:
        fan.plan(lambda: list(frames))
        fan.invite()
    for index in fan.chunks():
        with fan.working(index) as tiers:
            for frame_id in fan.items(index):
                if (frame := frames.get(frame_id)) is None:
                    continue  # uploaded after the owner planned, or deleted
                _, tier = cached_embedding(
                    predictor,
                    cache,
                    frame.sha256,
                    functools.partial(frame_rgb, storage, frame),
                    (frame.height, frame.width),
                )
                tiers[tier] = tiers.get(tier, 0) + 1
                ctx.check_cancelled()
        ctx.progress(fan.progress(), fan.message())
    if ctx.helper:
        return {}
    tiers = {name: 0 for name in ("computed", "memory", "disk", "shared")}
    for result in fan.results():
        for name, count in result.items():
            tiers[name] += count
    ctx.summary = (
        f"{counted(tiers['computed'], 'embedding')} computed, "
        f"{fan.size - tiers['computed']} already cached"
    )
    return {"frames": fan.size, **tiers}
