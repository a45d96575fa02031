"""Recording a proposal: the teacher's, the student's and propagation's go through
``record_proposal``, which stores the files and the row in one guarded write, moves a new frame
to ``proposed`` and rescores it for the review queue."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session, sessionmaker

from app.core.db import updated_one
from app.core.housekeeping import doom
from app.core.models import (
    Frame,
    FrameStatus,
    Job,
    JobStatus,
    Label,
    LabelRevision,
    Proposal,
    ProposalClaim,
)
from app.proposals.files import writing_for_frame
from app.proposals.queue import rescore_frame
from app.storage import Storage

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

TEACHER, STUDENT, PROPAGATED = "teacher", "student", "propagated"
"""The proposal sources (``Proposal.source``)."""


def has_proposal(session: Session, frame_id: int, model_id: str) -> bool:
    return (
        session.scalar(
            sa.select(Proposal.id).where(
                Proposal.frame_id == frame_id, Proposal.model_id == model_id
            )
        )
        is not None
    )


def claim(
    session_factory: sessionmaker[Session], frame_id: int, model_id: str, job_id: int
) -> bool:
    """Whether job ``job_id`` may propose frame ``frame_id`` with ``model_id`` now: True once
    it holds the frame's claim (new, already its own, or left by a run no longer running),
    False while another running run holds it (that run records the proposal). Each step is one
    guarded write, so of two runs racing for a frame one wins, on SQLite and PostgreSQL."""
    key = (ProposalClaim.frame_id == frame_id, ProposalClaim.model_id == model_id)
    with session_factory() as session:
        for _ in range(2):
            try:
                session.add(ProposalClaim(frame_id=frame_id, model_id=model_id, job_id=job_id))
                session.commit()
                return True
            except sa.exc.IntegrityError:
                session.rollback()
            holder = session.scalar(sa.select(ProposalClaim.job_id).where(*key))
            if holder is None:
                continue  # released meanwhile (or the frame is gone: its run finds that)
            if holder == job_id:
                return True
            if session.scalar(sa.select(Job.status).where(Job.id == holder)) == JobStatus.running:
                return False
            taken = updated_one(
                session,
                sa.update(ProposalClaim)
                .where(*key, ProposalClaim.job_id == holder)
                .values(job_id=job_id),
            )
            session.commit()
            return taken
    return True


def release(
    session_factory: sessionmaker[Session], frame_id: int, model_id: str, job_id: int
) -> None:
    """Give up job ``job_id``'s claim on the frame (its proposal is recorded, or it failed)."""
    with session_factory() as session:
        session.execute(
            sa.delete(ProposalClaim).where(
                ProposalClaim.frame_id == frame_id,
                ProposalClaim.model_id == model_id,
                ProposalClaim.job_id == job_id,
            )
        )
        session.commit()


def _drop_earlier(session: Session, frame_id: int, source: str) -> None:
    """Delete the frame's earlier proposals of ``source``, except those a label (or one of
    its revisions) started from: they are the label's history."""
    started_from = sa.union(
        sa.select(Label.proposal_id).where(
            Label.frame_id == frame_id, Label.proposal_id.is_not(None)
        ),
        sa.select(LabelRevision.proposal_id).where(
            LabelRevision.frame_id == frame_id, LabelRevision.proposal_id.is_not(None)
        ),
    )
    dropped = (
        Proposal.frame_id == frame_id,
        Proposal.source == source,
        Proposal.id.not_in(started_from),
    )
    files = session.execute(sa.select(Proposal.mask_path, Proposal.heatmap_path).where(*dropped))
    doom(session, {path for row in files for path in row if path})  # the collector's, later
    session.execute(sa.delete(Proposal).where(*dropped))


def record_proposal(
    session: Session,
    storage: Storage,
    frame: Frame,
    *,
    source: str,
    model_id: str,
    mask: NDArray[np.bool_],
    heatmap: NDArray[np.float32] | None,
    keypoints: list[list[float]],
    scores: dict[str, Any],
    weights: Mapping[str, float],
    job_id: int | None = None,
    model_version_id: int | None = None,
    prompts: dict[str, Any] | None = None,
    timings: dict[str, Any] | None = None,
    replace_earlier: bool = False,
    frame_fields: Mapping[str, Any] | None = None,
) -> Proposal:
    """Store a proposal as the frame's newest: its mask (and heatmap, channel 0 of Algorithm
    1's array) under artefacts/, the row with ``scores`` and the mask's area fraction, the
    frame ``proposed`` if it was new, and its queue score recomputed. ``replace_earlier``
    first drops the frame's earlier proposals of the same source (not those a label started
    from); ``frame_fields`` are set on the frame in the same write. FrameDeleted when the frame
    went meanwhile; nothing is then left behind."""
    with writing_for_frame(session, storage, frame.id) as write:
        for name, value in (frame_fields or {}).items():
            setattr(frame, name, value)
        if replace_earlier:
            _drop_earlier(session, frame.id, source)
        proposal = Proposal(
            frame_id=frame.id,
            source=source,
            model_id=model_id,
            model_version_id=model_version_id,
            job_id=job_id,
            mask_path=write.mask(mask),
            heatmap_path=None if heatmap is None else write.heatmap(heatmap),
            keypoints=keypoints,
            prompts=prompts or {},
            scores=scores | {"mask_fraction": float(mask.mean())},
            timings=timings or {},
        )
        session.add(proposal)
        if frame.status == FrameStatus.new:
            frame.status = FrameStatus.proposed
        session.flush()
        rescore_frame(session, frame, weights)
    return proposal


def record_teacher_proposal(
    session: Session,
    storage: Storage,
    frame: Frame,
    result: Any,
    model_id: str,
    job_id: int | None,
    weights: Mapping[str, float],
) -> Proposal:
    """A TeacherResult as the frame's newest proposal; the frame keeps its DINO descriptor
    (the queue's diversity) and loses its last teacher error."""
    descriptor = np.asarray(result.attention.cls, np.float32)
    return record_proposal(
        session,
        storage,
        frame,
        source=TEACHER,
        model_id=model_id,
        mask=result.mask,
        heatmap=result.heatmap,
        keypoints=result.keypoints,
        scores={
            "sam2_iou": result.score,
            "object_score": result.object_score,
            "prompt_stability": result.prompt_stability,
            "warning": result.warning,
            "keypoint_rules": result.keypoint_rules,
        },
        weights=weights,
        job_id=job_id,
        prompts=result.prompts.as_dict(),
        timings=result.timings,
        frame_fields={"descriptor": descriptor, "teacher_error": None},
    )
