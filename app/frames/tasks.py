"""Background work of the frames domain: extracting frames from an uploaded video."""

from __future__ import annotations

from typing import Any

from app.db import session_scope
from app.frames.service import extract_video_frames
from app.jobs.registry import JobContext, job_handler
from app.models import User, Video
from app.storage import Storage
from weldpool_core.errors import InvalidInputError


@job_handler("extract_video", max_attempts=2)
def extract_video(ctx: JobContext) -> dict[str, Any]:
    """Every n-th frame of a stored video into its sequence; a lost run is simply re-run
    (frames it already stored count as duplicates)."""
    with session_scope(ctx.session_factory) as session:
        video = session.get(Video, int(ctx.params["video_id"]))
        if video is None:
            raise InvalidInputError(f"Video {ctx.params['video_id']} no longer exists.")
        user = session.get(User, video.uploaded_by_id) if video.uploaded_by_id else None
        result = extract_video_frames(
            session, Storage(ctx.settings.home), video, user=user, progress=ctx.progress
        )
    ctx.progress(1.0, f"{result['frames']} frames stored")
    return result
