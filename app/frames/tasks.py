"""Background work of the frames domain: extracting frames from an uploaded video (then, when
SAM2's weights are here, a job that embeds the run's frames ahead of review)."""

from __future__ import annotations

from typing import Any

from app.core.db import session_scope
from app.core.models import User, Video
from app.frames.videos import extract_video_frames
from app.jobs.registry import JobContext, counted, job_handler
from app.jobs.service import create_job
from app.storage import open_storage
from app.system.status import sam2_problem
from weldpool_core.errors import InvalidInputError


@job_handler("extract_video", max_attempts=2, lane="quick")
def extract_video(ctx: JobContext) -> dict[str, Any]:
    """Every n-th frame of a stored video into its sequence; a lost run is simply re-run
    (frames it already stored count as duplicates)."""
    with session_scope(ctx.session_factory) as session:
        video = session.get(Video, int(ctx.params["video_id"]))
        if video is None:
            raise InvalidInputError(f"Video {ctx.params['video_id']} no longer exists.")
        user = session.get(User, video.uploaded_by_id) if video.uploaded_by_id else None
        video_sequence = video.sequence_id
        result = extract_video_frames(
            session, open_storage(ctx.settings), video, user=user, progress=ctx.progress
        )
    ctx.summary = f"{counted(result['frames'], 'frame')} stored in sequence #{video_sequence}" + (
        f" ({result['duplicates']} were already there)" if result["duplicates"] else ""
    )
    if result["frames"] and ctx.queue is not None and sam2_problem(ctx.settings) is None:
        # The run's embeddings next, so that the first click on any of its frames is quick.
        with ctx.session_factory() as session:
            create_job(session, ctx.queue, "embed", {"sequence_id": video_sequence}, None)
    return result
