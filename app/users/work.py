"""Whose work a frame is, and how much each person has waiting: the rule behind
``GET /users/me/work``, the header's badge and ``GET /frames?assignee=me``.

A frame is a person's work while it is handed to them (``Frame.assignee_id``) and either still
to review (new or proposed) or sent back to them: a reviewer who sends a label back hands the
frame to the annotator who saved it. A label awaiting approval is every reviewer's work (any
reviewer may decide), none of its annotator's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.models import UNREVIEWED, Frame, Label, ReviewState, Role, User


def sent_back() -> Any:
    """Frames whose label a reviewer sent back (a condition on ``Frame``)."""
    return Frame.id.in_(sa.select(Label.frame_id).where(Label.review == ReviewState.returned))


def still_to_review() -> Any:
    """Frames nobody has labelled yet (new or proposed)."""
    return Frame.status.in_(UNREVIEWED)


def work_of(user_id: int) -> Any:
    """The frames that are ``user_id``'s to do: handed to them, and sent back or still to review."""
    return sa.and_(Frame.assignee_id == user_id, sa.or_(sent_back(), still_to_review()))


def work_order() -> Any:
    """What comes first in a person's work list: what was sent back (0), then the rest (1)."""
    return sa.case((sent_back(), 0), else_=1)


@dataclass(frozen=True)
class Work:
    """A person's work as counts (``GET /users/me/work``)."""

    sent_back: int
    assigned: int
    awaiting_review: int


def work_counts(session: Session, user: User) -> Work:
    """The caller's work: labels sent back to them, frames handed to them still to review, and
    (reviewers) labels awaiting a reviewer's approval."""
    mine = Frame.assignee_id == user.id
    returned = session.scalar(sa.select(sa.func.count(Frame.id)).where(mine, sent_back()))
    assigned = session.scalar(sa.select(sa.func.count(Frame.id)).where(mine, still_to_review()))
    awaiting: int | None = 0
    if user.role.rank >= Role.reviewer.rank:
        awaiting = session.scalar(
            sa.select(sa.func.count(Label.id)).where(Label.review == ReviewState.awaiting)
        )
    return Work(int(returned or 0), int(assigned or 0), int(awaiting or 0))
