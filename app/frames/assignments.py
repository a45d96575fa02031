"""Frames handed to a person: a selection, or the next frames of the review queue.

An assignment is advice, not a lock: anyone who may review a frame still may, and the
assignee's queue (``GET /frames?assignee=me``) shows what is theirs. Handing out "the next N"
takes the queue's order (most uncertain first, still to review) and skips frames already
handed to someone, so two reviewers handing out work do not hand out the same frames.
"""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.db import utcnow
from app.errors import InvalidInputError, NotFoundError
from app.frames.listing import list_query
from app.frames.sequences import get_sequence
from app.models import Frame, User

MAX_NEXT = 1000
"""Most frames one "next N of the queue" hands out."""


def assignee(session: Session, assignee_id: int | None) -> User | None:
    """The active user frames are handed to (None: nobody); 404 / 400 in one sentence."""
    if assignee_id is None:
        return None
    user = session.get(User, assignee_id)
    if user is None:
        raise NotFoundError(f"There is no user {assignee_id}.")
    if not user.is_active:
        raise InvalidInputError(f"{user.username} is deactivated; reactivate them first.")
    return user


def assign_frames(
    session: Session,
    assignee_id: int | None,
    *,
    frame_ids: list[int] | None = None,
    next_count: int | None = None,
    sequence_id: int | None = None,
) -> list[int]:
    """Hand ``frame_ids`` (all must exist), or the next ``next_count`` unassigned frames of
    the queue (of ``sequence_id`` when given), to ``assignee_id`` (None: take them back).
    Returns the frames handed, in the order given or the queue's."""
    if frame_ids is not None and next_count is not None:
        raise InvalidInputError("Give either frame_ids or next, not both.")
    if frame_ids is None and next_count is None:
        raise InvalidInputError("Give frame_ids or next: which frames to hand.")
    person = assignee(session, assignee_id)
    if sequence_id is not None:
        get_sequence(session, sequence_id)
    if frame_ids is not None:
        ids = list(dict.fromkeys(frame_ids))
        found = set(session.scalars(sa.select(Frame.id).where(Frame.id.in_(ids))))
        missing = [i for i in ids if i not in found]
        if missing:
            raise NotFoundError(f"There is no frame {missing[0]}.")
    else:
        queue, _ = list_query(sequence_id=sequence_id, status="unreviewed", order="uncertainty")
        queue = queue.where(Frame.assignee_id.is_(None)).limit(next_count)
        ids = list(session.scalars(queue.with_only_columns(Frame.id)))
    if ids:
        session.execute(
            sa.update(Frame)
            .where(Frame.id.in_(ids))
            .values(
                assignee_id=person.id if person else None,
                assigned_at=utcnow() if person else None,
            )
        )
    session.commit()
    return ids
