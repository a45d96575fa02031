"""Frames handed to a person: a selection, or the next frames of the review queue.

An assignment is advice, not a lock: anyone who may review a frame still may, and the
assignee's queue (``GET /frames?assignee=me``) shows what is theirs. Handing out "the next N"
takes the queue's order (most uncertain first, still to review) and skips frames already
handed to someone, so two reviewers handing out work do not hand out the same frames: each
frame is taken by a conditional update that only an unassigned frame passes.
"""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import utcnow
from app.core.errors import InvalidInputError, NotFoundError
from app.core.models import Frame, User
from app.frames.listing import list_query
from app.frames.sequences import get_sequence

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
    if frame_ids is None:
        ids = _take_next(session, person, next_count or 0, sequence_id)
    else:
        ids = list(dict.fromkeys(frame_ids))
        found = set(session.scalars(sa.select(Frame.id).where(Frame.id.in_(ids))))
        missing = [i for i in ids if i not in found]
        if missing:
            raise NotFoundError(f"There is no frame {missing[0]}.")
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


def _take_next(
    session: Session, person: User | None, count: int, sequence_id: int | None
) -> list[int]:
    """Hand the next ``count`` unassigned frames of the queue to ``person``, in its order.

    A frame is taken only where it is still nobody's (``assignee_id IS NULL`` in the update's
    WHERE): a frame another reviewer took between the read and the update is skipped (on
    PostgreSQL the update waits for their commit, then sees it assigned), and the queue is read
    again until ``count`` are taken or none is left.
    """
    taken: list[int] = []
    queue, _ = list_query(sequence_id=sequence_id, status="unreviewed", order="uncertainty")
    queue = queue.where(Frame.assignee_id.is_(None)).with_only_columns(Frame.id)
    if person is None:  # the next unassigned frames are nobody's already
        return list(session.scalars(queue.limit(count)))
    while len(taken) < count:
        candidates = list(session.scalars(queue.limit(count - len(taken))))
        if not candidates:
            break
        won = set(
            session.scalars(
                sa.update(Frame)
                .where(Frame.id.in_(candidates), Frame.assignee_id.is_(None))
                .values(assignee_id=person.id, assigned_at=utcnow())
                .returning(Frame.id)
            )
        )
        taken += [i for i in candidates if i in won]
    return taken
