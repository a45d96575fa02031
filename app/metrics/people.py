"""Per-person figures of the review loop (``GET /metrics/people``): what each person saved, how
fast, how often a reviewer sent it back and how far it was from what was approved; for
reviewers, their decisions and how long a label waited for them.

Everything is read from the label history (``LabelRevision``), walked frame by frame:

- a **decision** is a revision by which a label that awaited review became approved or sent
  back; it is a plain *approve* or *send back* when the content stayed as it was, a
  *correct and approve* when the reviewer changed it in the same step;
- a **save** is every other revision, and a correct-and-approve (labels imported from a file
  are nobody's work and count for no one); a save that awaits review is a **submission**;
- **active time**: a save counts the time since its author's previous save or decision when
  that gap is at most ``IDLE_GAP_S`` (5 minutes); a longer gap is a pause and counts nothing.
  ``seconds_per_frame`` is that time over the saves it covers, ``frames_per_hour`` its inverse;
- **vs approved**: each submission against the approval that settled its frame next (sent
  back ones included): the mask IoU, and the mean distance in pixels from each approved
  keypoint to the nearest submitted one (a rejection against a mask: IoU 0, no distance);
- **turnaround**: from a submission to its decision; the median per reviewer.

The period (``since`` ≤ t < ``until``) selects saves and submissions by when they were saved and
decisions by when they were made.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import itertools
import statistics
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import MissingFile
from app.core.models import LabelRevision, LabelStatus, ReviewState, User
from app.core.permissions import Action, may
from app.proposals.policy import stored_iou
from app.storage import Storage

IDLE_GAP_S = 300.0
"""A gap between two of a person's actions longer than this is a pause, not labelling time."""

COLUMNS = (
    "username",
    "role",
    "labels_saved",
    "submitted",
    "sent_back",
    "sent_back_rate",
    "active_hours",
    "seconds_per_frame",
    "frames_per_hour",
    "compared_with_approved",
    "iou_vs_approved",
    "keypoint_px_vs_approved",
    "decisions",
    "approved",
    "corrected_and_approved",
    "returned",
    "turnaround_median_s",
)
"""The figures of one person, in the order of the CSV's columns."""


@dataclass
class _Person:
    saves: list[dt.datetime] = field(default_factory=list)
    actions: list[dt.datetime] = field(default_factory=list)
    submitted: int = 0
    decided: int = 0  # of their submissions in the period, those a reviewer decided on
    sent_back: int = 0
    ious: list[float] = field(default_factory=list)
    distances: list[float] = field(default_factory=list)
    decisions: dict[str, int] = field(
        default_factory=lambda: dict.fromkeys(("approved", "corrected_and_approved", "returned"), 0)
    )
    turnarounds: list[float] = field(default_factory=list)


def _same_content(a: LabelRevision, b: LabelRevision) -> bool:
    return (a.status, a.mask_path, a.keypoints) == (b.status, b.mask_path, b.keypoints)


def _nearest_distance(approved: list[Any] | None, submitted: list[Any] | None) -> float | None:
    """Mean distance from each approved keypoint to the nearest submitted one (px)."""
    if not approved or not submitted:
        return None
    return statistics.fmean(
        min(((ax - sx) ** 2 + (ay - sy) ** 2) ** 0.5 for sx, sy in submitted) for ax, ay in approved
    )


def _iou(storage: Storage, submitted: LabelRevision, approved: LabelRevision) -> float | None:
    """Mask IoU of a submission and its approval (both rejections: 1; one of them: 0)."""
    if submitted.mask_path == approved.mask_path:
        return 1.0
    if submitted.mask_path is None or approved.mask_path is None:
        return 0.0
    try:
        return stored_iou(
            storage.existing(submitted.mask_path), storage.existing(approved.mask_path)
        )
    except MissingFile:  # a lost mask scores nothing (`weldpool doctor` lists it)
        return None


class _Walk:
    """One pass over the history, frame by frame, collecting each person's figures."""

    def __init__(self, storage: Storage, since: dt.datetime | None, until: dt.datetime | None):
        self.storage = storage
        self.since, self.until = since, until
        self.people: dict[int, _Person] = defaultdict(_Person)

    def within(self, moment: dt.datetime) -> bool:
        return (self.since is None or moment >= self.since) and (
            self.until is None or moment < self.until
        )

    def frame(self, chain: list[LabelRevision]) -> None:
        previous: LabelRevision | None = None
        for index, revision in enumerate(chain):
            decision = (
                previous is not None
                and previous.review == ReviewState.awaiting
                and revision.review in (ReviewState.approved, ReviewState.returned)
            )
            if decision and previous is not None:
                self.decision(previous, revision)
            if not (decision and previous is not None and _same_content(previous, revision)):
                self.save(revision, chain[index + 1 :])
            if (
                revision.user_id is not None
                and revision.source is None
                and self.within(revision.created_at)
            ):
                self.people[revision.user_id].actions.append(revision.created_at)
            previous = revision

    def decision(self, submission: LabelRevision, revision: LabelRevision) -> None:
        if submission.user_id is not None and self.within(submission.created_at):
            author = self.people[submission.user_id]
            author.decided += 1
            author.sent_back += revision.review == ReviewState.returned
        if revision.user_id is None or not self.within(revision.created_at):
            return
        reviewer = self.people[revision.user_id]
        kind = (
            "returned"
            if revision.review == ReviewState.returned
            else "approved"
            if _same_content(submission, revision)
            else "corrected_and_approved"
        )
        reviewer.decisions[kind] += 1
        reviewer.turnarounds.append((revision.created_at - submission.created_at).total_seconds())

    def save(self, revision: LabelRevision, later: list[LabelRevision]) -> None:
        if revision.user_id is None or revision.source is not None:
            return
        if not self.within(revision.created_at):
            return
        person = self.people[revision.user_id]
        person.saves.append(revision.created_at)
        if revision.review != ReviewState.awaiting:
            return
        person.submitted += 1
        approval = next((r for r in later if r.review == ReviewState.approved), None)
        if approval is None:
            return
        iou = _iou(self.storage, revision, approval)
        if iou is not None:
            person.ious.append(iou)
        if approval.status != LabelStatus.rejected and revision.status != LabelStatus.rejected:
            distance = _nearest_distance(approval.keypoints, revision.keypoints)
            if distance is not None:
                person.distances.append(distance)


def _active(person: _Person) -> tuple[float, int]:
    """Active seconds and the saves they cover (module doc)."""
    moments = sorted(person.actions)
    saves = set(person.saves)
    seconds, timed = 0.0, 0
    for before, moment in itertools.pairwise(moments):
        gap = (moment - before).total_seconds()
        if moment in saves and gap <= IDLE_GAP_S:
            seconds += gap
            timed += 1
    return seconds, timed


def _mean(values: list[float]) -> float | None:
    return statistics.fmean(values) if values else None


def _row(user: User, person: _Person) -> dict[str, Any]:
    seconds, timed = _active(person)
    decisions = person.decisions
    return {
        "user_id": user.id,
        "username": user.username,
        "role": user.role.value,
        "labels_saved": len(person.saves),
        "submitted": person.submitted,
        "sent_back": person.sent_back,
        "sent_back_rate": person.sent_back / person.decided if person.decided else None,
        "active_hours": seconds / 3600,
        "seconds_per_frame": seconds / timed if timed else None,
        "frames_per_hour": 3600 * timed / seconds if seconds else None,
        "compared_with_approved": len(person.ious),
        "iou_vs_approved": _mean(person.ious),
        "keypoint_px_vs_approved": _mean(person.distances),
        "decisions": sum(decisions.values()),
        **decisions,
        "turnaround_median_s": (
            statistics.median(person.turnarounds) if person.turnarounds else None
        ),
    }


def people_figures(
    session: Session,
    storage: Storage,
    viewer: User,
    since: dt.datetime | None = None,
    until: dt.datetime | None = None,
) -> list[dict[str, Any]]:
    """One row per user (module doc), by name; an annotator gets her own row only."""
    walk = _Walk(storage, since, until)
    query = sa.select(LabelRevision).order_by(LabelRevision.frame_id, LabelRevision.revision)
    if since is not None or until is not None:  # the frames with something in the period
        moment = LabelRevision.created_at
        active = sa.select(LabelRevision.frame_id).where(
            *([moment >= since] if since is not None else []),
            *([moment < until] if until is not None else []),
        )
        query = query.where(LabelRevision.frame_id.in_(active))
    revisions = session.scalars(query)
    chain: list[LabelRevision] = []
    for revision in revisions:
        if chain and chain[-1].frame_id != revision.frame_id:
            walk.frame(chain)
            chain = []
        chain.append(revision)
    if chain:
        walk.frame(chain)
    users = sa.select(User).order_by(sa.func.lower(User.username))
    if not may(viewer, Action.review):
        users = users.where(User.id == viewer.id)
    return [_row(user, walk.people.get(user.id, _Person())) for user in session.scalars(users)]


def people_csv(rows: list[dict[str, Any]]) -> str:
    """The figures as CSV, one row per person (``COLUMNS``)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow(["" if row[c] is None else _cell(row[c]) for c in COLUMNS])
    return out.getvalue()


def _cell(value: Any) -> Any:
    return f"{value:.4f}".rstrip("0").rstrip(".") if isinstance(value, float) else value
