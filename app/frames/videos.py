"""Videos: the stored file of a weld run's video and the frames extracted from it."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import InvalidInputError
from app.core.models import User, Video
from app.frames.ingest import INGEST_POOL, CheckedFrame, name_problem, record_frames
from app.frames.sequences import create_sequence, get_sequence, unique_sequence_name
from app.storage import Storage
from app.storage.spool import put_upload
from weldpool_core.io import EXTENSIONS, MEDIA_TYPES, ImageInfo, encode_png
from weldpool_core.video import probe_video, sniff_container


def store_video(
    session: Session,
    storage: Storage,
    source: BinaryIO,
    *,
    name: str,
    every_nth: int,
    sequence_id: int | None,
    user: User | None,
) -> Video:
    """Store a video file and record it, after checking that it decodes; the frames are
    extracted separately (a job in the service, in-process on the command line). An upload
    spooled into the store's scratch folder is renamed into place, written once
    (``put_upload``); the file goes again if the video is refused."""
    problem = name_problem(name)
    if problem:
        raise InvalidInputError(problem)
    if every_nth < 1:
        raise InvalidInputError("every_nth must be 1 or more.")
    sequence = get_sequence(session, sequence_id) if sequence_id is not None else None
    head = source.read(16)
    if not head:
        raise InvalidInputError("The file is empty.")
    container = sniff_container(head)
    if container is None:
        raise InvalidInputError("The file is not a video; upload an MP4 or AVI video.")
    source.seek(0)
    stored, sha256, size = put_upload(storage, source, f".{container}", "videos")
    try:
        info = probe_video(storage.absolute(stored.path))
        if sequence is None:
            base = Path(name).stem or "video"
            sequence = create_sequence(session, {"name": unique_sequence_name(session, base)}, user)
        video = Video(
            sequence_id=sequence.id,
            sha256=sha256,
            path=stored.path,
            original_name=name,
            container=container,
            size_bytes=size,
            width=info.width,
            height=info.height,
            fps=info.fps,
            frame_count=info.frame_count,
            every_nth=every_nth,
            uploaded_by_id=user.id if user else None,
        )
        session.add(video)
        session.commit()
    except BaseException as exc:
        session.rollback()
        in_use = set(session.scalars(sa.select(Video.path).where(Video.path == stored.path)))
        storage.discard([stored], in_use)
        if isinstance(exc, sa.exc.IntegrityError) and sequence_id is not None:
            get_sequence(session, sequence_id)  # deleted meanwhile: its 404
        raise
    return video


def encode_video_frame(index: int, timestamp_s: float, pixels: Any, name: str) -> CheckedFrame:
    """A decoded video frame as a lossless PNG ready to be recorded."""
    data = encode_png(pixels)
    height, width = pixels.shape[:2]
    info = ImageInfo(
        format="PNG",
        media_type=MEDIA_TYPES["PNG"],
        extension=EXTENSIONS["PNG"],
        width=width,
        height=height,
        channels=1 if pixels.ndim == 2 else pixels.shape[2],
        bit_depth=8,
    )
    return CheckedFrame(name, data, hashlib.sha256(data).hexdigest(), info, index, timestamp_s)


def extract_video_frames(
    session: Session,
    storage: Storage,
    video: Video,
    *,
    user: User | None,
    progress: Callable[[float, str], None],
    batch_size: int = 32,
) -> dict[str, int]:
    """Every n-th frame of ``video`` into its sequence, recorded batch by batch with progress.

    Re-running it is harmless: frames already stored are reported as duplicates.
    """
    from weldpool_core.video import iter_video_frames

    stem = Path(video.original_name).stem or f"video{video.id}"
    expected = max(1, -(-video.frame_count // video.every_nth))
    stored = duplicates = done = 0
    batch: list[Any] = []

    def flush() -> None:
        nonlocal stored, duplicates, done
        checked = list(
            INGEST_POOL.map(
                lambda f: encode_video_frame(
                    f.index, f.timestamp_s, f.pixels, f"{stem}_f{f.index:06d}.png"
                ),
                batch,
            )
        )
        result = record_frames(
            session, storage, checked, sequence_id=video.sequence_id, user=user, video_id=video.id
        )
        stored += len(result.stored)
        duplicates += len(result.duplicates)
        done += len(batch)
        batch.clear()
        progress(min(done / expected, 0.999), f"{done} of about {expected} frames")

    for frame in iter_video_frames(storage.absolute(video.path), video.every_nth):
        batch.append(frame)
        if len(batch) == batch_size:
            flush()
    if batch:
        flush()
    return {
        "video_id": video.id,
        "frames": stored,
        "duplicates": duplicates,
        "sequence_id": video.sequence_id,
    }
