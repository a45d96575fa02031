"""Guards on a frame's row for writers that may race its deletion: whether it is still there
(asked outside the caller's snapshot), and row locks that make a deletion wait for a commit."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import NotFoundError
from app.core.models import Frame


class FrameDeleted(NotFoundError):
    """A job's frame was deleted while the job worked on it; nothing was recorded for it."""

    def __init__(self, frame_id: int) -> None:
        super().__init__(f"Frame {frame_id} was deleted meanwhile; nothing was recorded for it.")
        self.frame_id = frame_id


def frame_exists(session: Session, frame_id: int) -> bool:
    """Whether the frame is there now (asked on a connection of its own, so a long read
    transaction's snapshot cannot hide a deletion)."""
    with Session(session.get_bind()) as fresh:
        return fresh.scalar(sa.select(Frame.id).where(Frame.id == frame_id)) is not None


def lock_frame(session: Session, frame_id: int) -> None:
    """Lock the frame's row until the commit (PostgreSQL; a deletion then waits for it), or
    raise FrameDeleted when it is gone."""
    locked = sa.select(Frame.id).where(Frame.id == frame_id).with_for_update()
    if session.execute(locked).first() is None:
        raise FrameDeleted(frame_id)


def lock_frames(session: Session, frame_ids: list[int]) -> set[int]:
    """``lock_frame`` for many frames in one query (ids in order, so that two writers lock
    alike); the ids of those still there."""
    locked = sa.select(Frame.id).where(Frame.id.in_(sorted(frame_ids))).order_by(Frame.id)
    return set(session.scalars(locked.with_for_update()))
