"""Deleting frames and weld runs, with the files no other row names."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import changed, updated_one
from app.core.errors import ConflictError, NotFoundError
from app.core.housekeeping import collect_doomed, doom
from app.core.models import (
    Frame,
    FrameStatus,
    Label,
    LabelRevision,
    OverlapLabel,
    Proposal,
    Sequence,
    ValidationKeypoints,
    Video,
)
from app.frames.sequences import get_sequence
from app.storage import Storage

T = TypeVar("T")

REVIEWED = (FrameStatus.accepted, FrameStatus.corrected, FrameStatus.rejected)


@dataclass
class Deletion:
    """What a deletion removed."""

    frames: int = 0
    reviewed: int = 0
    files: int = 0


def _chunks(items: list[T]) -> list[list[T]]:
    """``items`` 500 at a time (an IN list each database takes)."""
    return [items[start : start + 500] for start in range(0, len(items), 500)]


def _files_of(session: Session, frame_ids: list[int], video_ids: list[int]) -> set[str]:
    paths: set[str] = set()
    for chunk in _chunks(frame_ids):
        for column, owner in (
            (Frame.path, Frame.id),
            (Proposal.mask_path, Proposal.frame_id),
            (Proposal.heatmap_path, Proposal.frame_id),
            (Label.mask_path, Label.frame_id),
            (LabelRevision.mask_path, LabelRevision.frame_id),
            (OverlapLabel.mask_path, OverlapLabel.frame_id),
        ):
            paths.update(p for p in session.scalars(sa.select(column).where(owner.in_(chunk))) if p)
    if video_ids:
        paths.update(session.scalars(sa.select(Video.path).where(Video.id.in_(video_ids))))
    return paths


def _all_there(session: Session, frame_ids: list[int], run_id: int | None) -> None:
    """Raise NotFoundError naming the first of ``frame_ids`` that is not stored, or the run
    ``run_id`` when it is gone (another deletion took it with them)."""
    found: set[int] = set()
    for chunk in _chunks(frame_ids):
        found.update(session.scalars(sa.select(Frame.id).where(Frame.id.in_(chunk))))
    if missing := [i for i in frame_ids if i not in found]:
        if run_id is not None:
            get_sequence(session, run_id)
        raise NotFoundError(f"There is no frame {missing[0]}; nothing was deleted.")


def _delete(session: Session, where: sa.ColumnElement[bool]) -> int:
    """Delete the frames ``where`` holds; how many there were."""
    return changed(session, sa.delete(Frame).where(where))


def delete_frames(
    session: Session,
    storage: Storage,
    frame_ids: list[int],
    *,
    force: bool,
    sequence: Sequence | None = None,
) -> Deletion:
    """Delete frames (or a whole sequence with its frames and videos) in one transaction.

    Proposals, labels with their history, annotators' own labels (agreement) and validation
    keypoints go with their frame. Frames
    a person reviewed (accepted, corrected, rejected, or with validation keypoints) are only
    deleted with ``force``; otherwise ConflictError says how many would be lost. After the
    commit the collector removes each file no remaining row names (content is shared by hash)
    unless an upload in flight claimed it; what it leaves, and what a crash in between leaves,
    the collector sweeps later.
    """
    frame_ids = sorted(set(frame_ids))
    run_id = sequence.id if sequence is not None else None
    _all_there(session, frame_ids, run_id)
    reviewed = 0
    for chunk in _chunks(frame_ids):
        reviewed += (
            session.scalar(
                sa.select(sa.func.count())
                .select_from(Frame)
                .where(
                    Frame.id.in_(chunk),
                    Frame.status.in_(REVIEWED)
                    | Frame.id.in_(
                        sa.select(ValidationKeypoints.frame_id).where(
                            ValidationKeypoints.frame_id.in_(chunk)
                        )
                    ),
                )
            )
            or 0
        )
    if reviewed and not force:
        what = f"sequence {sequence.name!r}" if sequence else "the selection"
        raise ConflictError(
            f"{reviewed} frame{'s' * (reviewed != 1)} of {what} "
            f"{'have' if reviewed != 1 else 'has'} reviewed labels or validation keypoints "
            "that would be lost; delete with force=true to remove them too."
        )
    video_ids = (
        list(session.scalars(sa.select(Video.id).where(Video.sequence_id == sequence.id)))
        if sequence
        else []
    )
    paths = _files_of(session, frame_ids, video_ids)
    deleted = sum(_delete(session, Frame.id.in_(chunk)) for chunk in _chunks(frame_ids))
    if deleted < len(frame_ids):  # another deletion took some since they were read
        session.rollback()
        _all_there(session, frame_ids, run_id)
        raise ConflictError("The frames changed while they were deleted; nothing was deleted.")
    if sequence is not None:
        # Frames uploaded into the run since its frames were read go with it (and are counted).
        deleted += _delete(session, Frame.sequence_id == sequence.id)
        session.execute(sa.delete(Video).where(Video.sequence_id == sequence.id))
        if not updated_one(session, sa.delete(Sequence).where(Sequence.id == run_id)):
            # another deletion was first
            session.rollback()
            raise NotFoundError(f"There is no sequence {run_id}.")
    doom(session, paths)  # with the rows: a crash after the commit leaves them recorded
    session.commit()
    removed = collect_doomed(session, storage, paths)
    return Deletion(frames=deleted, reviewed=reviewed, files=len(removed))


def delete_sequence(
    session: Session, storage: Storage, sequence: Sequence, *, force: bool
) -> Deletion:
    """A weld run with its frames and videos (see ``delete_frames`` for the guard). The run's
    row is locked first (PostgreSQL): an upload into it then waits, and finds it gone."""
    locked = sa.select(Sequence.id).where(Sequence.id == sequence.id).with_for_update()
    if session.execute(locked).first() is None:  # another deletion took it while this waited
        raise NotFoundError(f"There is no sequence {sequence.id}.")
    frame_ids = list(session.scalars(sa.select(Frame.id).where(Frame.sequence_id == sequence.id)))
    return delete_frames(session, storage, frame_ids, force=force, sequence=sequence)
