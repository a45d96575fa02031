"""Quality figures of the loop: the student's learning curve, the teacher against reviewed
masks, and how reviewers receive the teacher's proposals."""

from __future__ import annotations

from collections import defaultdict
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session, aliased

from app.core.errors import MissingFile
from app.core.models import (
    Frame,
    Label,
    LabelRevision,
    LabelStatus,
    ModelVersion,
    Proposal,
    Sequence,
)
from app.metrics.classes import class_figures
from app.proposals.policy import current, source_key, stored_iou
from app.review.agreement import run_agreement
from app.storage import Storage

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np


def student_curve(session: Session) -> list[dict[str, Any]]:
    """Each student version's validation mIoU and mED against its number of training labels."""
    versions = session.scalars(sa.select(ModelVersion).order_by(ModelVersion.id))
    return [
        {
            "id": v.id,
            "name": v.name,
            "created_at": v.created_at.isoformat(),
            "train_label_count": v.train_label_count,
            "mIoU": v.metrics.get("mIoU"),
            "mED": v.metrics.get("mED"),
            "promoted": v.is_promoted,
        }
        for v in versions
    ]


def _summary(values: list[float]) -> dict[str, Any]:
    if not values:
        return {"frames": 0, "mIoU": None, "q1": None, "median": None, "q3": None}
    q1, median, q3 = (float(q) for q in np.percentile(values, [25, 50, 75]))
    return {
        "frames": len(values),
        "mIoU": float(np.mean(values)),
        "q1": q1,
        "median": median,
        "q3": q3,
    }


def teacher_quality(session: Session, storage: Storage) -> dict[str, Any]:
    """The teacher's mask against the reviewed mask (accepted or corrected), per sequence.

    As the training gate does, the fair figures (``overall``, ``by_sequence``) leave out the
    labels that *are* the teacher's mask, accepted unchanged from a teacher proposal (the
    teacher scores 1.0 on them by construction); ``including_unchanged`` has every label and
    ``left_out`` counts those left out."""
    newest_teacher = (
        sa.select(Proposal.frame_id, sa.func.max(Proposal.id).label("proposal_id"))
        .where(Proposal.source == "teacher")
        .group_by(Proposal.frame_id)
        .subquery()
    )
    started_from = aliased(Proposal)
    taken = sa.and_(Label.mask_changed.is_(False), started_from.source == "teacher")
    rows = session.execute(
        sa.select(Sequence.id, Sequence.name, Proposal.mask_path, Label.mask_path, taken)
        .join(Frame, Frame.id == Label.frame_id)
        .outerjoin(Sequence, Sequence.id == Frame.sequence_id)
        .join(newest_teacher, newest_teacher.c.frame_id == Frame.id)
        .join(Proposal, Proposal.id == newest_teacher.c.proposal_id)
        .outerjoin(started_from, started_from.id == Label.proposal_id)
        .where(Label.status.in_([LabelStatus.accepted, LabelStatus.corrected]))
    )
    per_sequence: dict[tuple[int | None, str | None], list[float]] = defaultdict(list)
    everything: list[float] = []
    for sequence_id, name, teacher_mask, label_mask, unchanged in rows:
        if label_mask:
            try:
                iou = stored_iou(storage.existing(teacher_mask), storage.existing(label_mask))
            except MissingFile:  # a lost mask scores nothing (`weldpool doctor` lists it)
                continue
            everything.append(iou)
            if not unchanged:
                per_sequence[(sequence_id, name)].append(iou)
    fair = [v for values in per_sequence.values() for v in values]
    return {
        "overall": _summary(fair),
        "by_sequence": [
            {"sequence_id": sid, "sequence": name} | _summary(values)
            for (sid, name), values in sorted(
                per_sequence.items(), key=lambda item: str(item[0][1])
            )
        ],
        "including_unchanged": _summary(everything),
        "left_out": len(everything) - len(fair),
    }


def review_figures(session: Session) -> dict[str, Any]:
    """Label counts, how reviewers received each source's proposals, and reviews per day.

    ``by_source``: per source key (``teacher``, ``student:<version>``, …) the current labels
    that started from its proposals: accepted, corrected, rejected, and ``unchanged`` (saved
    with the proposal's mask as it was); ``acceptance_rate`` is unchanged / all its labels.
    """
    counts = dict.fromkeys(("accepted", "corrected", "rejected"), 0)
    by_source: dict[str, dict[str, int]] = {}
    rows = session.execute(
        sa.select(Label.status, Label.mask_changed, Proposal).outerjoin(
            Proposal, Proposal.id == Label.proposal_id
        )
    )
    for status, changed, proposal in rows:
        counts[status.value] += 1
        if proposal is None:
            continue
        figures = by_source.setdefault(
            source_key(proposal), dict.fromkeys((*counts, "unchanged"), 0)
        )
        figures[status.value] += 1
        figures["unchanged"] += int(status != LabelStatus.rejected and changed is False)
    sources = [
        {"source": key, "reviewed": sum(f[s] for s in counts)}
        | f
        | {"acceptance_rate": f["unchanged"] / max(1, sum(f[s] for s in counts))}
        for key, f in sorted(by_source.items())
    ]
    teacher = by_source.get("teacher")
    per_day: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(counts, 0))
    for status, created in session.execute(
        sa.select(LabelRevision.status, LabelRevision.created_at)
    ):
        per_day[created.date().isoformat()][status.value] += 1
    teacher_reviewed = sum(teacher[s] for s in counts) if teacher else 0
    return {
        "labels": counts,
        "by_source": sources,
        "teacher_acceptance_rate": (
            teacher["unchanged"] / teacher_reviewed if teacher and teacher_reviewed else None
        ),
        "teacher_reviewed": teacher_reviewed,
        "over_time": [{"day": day} | values for day, values in sorted(per_day.items())],
    }


def all_metrics(session: Session, storage: Storage) -> dict[str, Any]:
    """Everything `GET /api/v1/metrics` and the metrics page show."""
    scored = session.scalar(sa.select(sa.func.count()).where(Frame.uncertainty.is_not(None)))
    return {
        "policy": current(session, storage).as_dict(),
        "student": student_curve(session),
        "teacher": teacher_quality(session, storage),
        "review": review_figures(session),
        "agreement": run_agreement(session, storage),
        "classes": class_figures(session),
        "queue": {"scored_frames": int(scored or 0)},
    }
