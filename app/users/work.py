"""Whose work a frame is, and how much each person has waiting: the rule behind
``GET /users/me/work``, the header's badge and ``GET /frames?assignee=me``.

A frame is a person's work while it is handed to them (``Frame.assignee_id``) and either still
to review (new or proposed) or sent back to them: a reviewer who sends a label back hands the
frame to the annotator who saved it. A frame given to several annotators for agreement
(``OverlapLabel``) is each one's work until she has saved her own label of it. A label awaiting
approval is every reviewer's work (any reviewer may decide), none of its annotator's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.models import UNREVIEWED, Frame, Label, OverlapLabel, ReviewState, User
from app.core.permissions import Action, may


def sent_back() -> Any:
    """Frames whose label a reviewer sent back (a condition on ``Frame``)."""
    return Frame.id.in_(sa.select(Label.frame_id).where(Label.review == ReviewState.returned))


def still_to_review() -> Any:
    """Frames nobody has labelled yet (new or proposed)."""
    return Frame.status.in_(UNREVIEWED)


def own_label_due(user_id: int) -> Any:
    """Frames given to ``user_id`` among several whose own label she has not saved yet."""
    return Frame.id.in_(
        sa.select(OverlapLabel.frame_id).where(
            OverlapLabel.user_id == user_id, OverlapLabel.mask_path.is_(None)
        )
    )


def to_label(user_id: int) -> Any:
    """Frames ``user_id`` is to label: handed to them still to review, or their own label due."""
    return sa.or_(sa.and_(Frame.assignee_id == user_id, still_to_review()), own_label_due(user_id))


def work_of(user_id: int) -> Any:
    """The frames that are ``user_id``'s to do: sent back to them, or to label."""
    return sa.or_(sa.and_(Frame.assignee_id == user_id, sent_back()), to_label(user_id))


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
    """The caller's work: labels sent back to them, frames to label (handed to them still to
    review, or given to several with their own label due), and (reviewers) labels awaiting a
    reviewer's approval."""
    mine = Frame.assignee_id == user.id
    returned = session.scalar(sa.select(sa.func.count(Frame.id)).where(mine, sent_back()))
    assigned = session.scalar(sa.select(sa.func.count(Frame.id)).where(to_label(user.id)))
    awaiting: int | None = 0
    if may(user, Action.review):
        awaiting = session.scalar(
            sa.select(sa.func.count(Label.id)).where(Label.review == ReviewState.awaiting)
        )
    return Work(int(returned or 0), int(assigned or 0), int(awaiting or 0))
