"""Quality figures of the loop: the student's learning curve, the teacher against reviewed
masks, and how reviewers receive the teacher's proposals."""

from __future__ import annotations

from collections import defaultdict
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.models import Frame, Label, LabelRevision, LabelStatus, ModelVersion, Proposal, Sequence
from app.storage import Storage
from weldpool_core.io import read_mask
from weldpool_core.metrics import iou


@lru_cache(maxsize=65536)
def _iou(first: Path, second: Path) -> float:
    """IoU of two stored masks; paths are content-addressed, so the answer never changes."""
    return iou(read_mask(first), read_mask(second))


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
    """The teacher's mask against the reviewed mask (accepted or corrected), per sequence."""
    newest_teacher = (
        sa.select(Proposal.frame_id, sa.func.max(Proposal.id).label("proposal_id"))
        .where(Proposal.source == "teacher")
        .group_by(Proposal.frame_id)
        .subquery()
    )
    rows = session.execute(
        sa.select(Sequence.id, Sequence.name, Proposal.mask_path, Label.mask_path)
        .join(Frame, Frame.id == Label.frame_id)
        .outerjoin(Sequence, Sequence.id == Frame.sequence_id)
        .join(newest_teacher, newest_teacher.c.frame_id == Frame.id)
        .join(Proposal, Proposal.id == newest_teacher.c.proposal_id)
        .where(Label.status.in_([LabelStatus.accepted, LabelStatus.corrected]))
    )
    per_sequence: dict[tuple[int | None, str | None], list[float]] = defaultdict(list)
    for sequence_id, name, teacher_mask, label_mask in rows:
        if label_mask:
            per_sequence[(sequence_id, name)].append(
                _iou(storage.absolute(teacher_mask), storage.absolute(label_mask))
            )
    everything = [v for values in per_sequence.values() for v in values]
    return {
        "overall": _summary(everything),
        "by_sequence": [
            {"sequence_id": sid, "sequence": name} | _summary(values)
            for (sid, name), values in sorted(
                per_sequence.items(), key=lambda item: str(item[0][1])
            )
        ],
    }


def review_figures(session: Session) -> dict[str, Any]:
    """Label counts, the acceptance rate of teacher proposals, and reviews per day."""
    counts = dict.fromkeys(("accepted", "corrected", "rejected"), 0)
    on_teacher = dict.fromkeys(("accepted", "corrected", "rejected"), 0)
    rows = session.execute(
        sa.select(Label.status, Proposal.source).outerjoin(
            Proposal, Proposal.id == Label.proposal_id
        )
    )
    for status, source in rows:
        counts[status.value] += 1
        if source == "teacher":
            on_teacher[status.value] += 1
    reviewed = sum(on_teacher.values())
    per_day: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(counts, 0))
    for status, created in session.execute(
        sa.select(LabelRevision.status, LabelRevision.created_at)
    ):
        per_day[created.date().isoformat()][status.value] += 1
    return {
        "labels": counts,
        "teacher_acceptance_rate": on_teacher["accepted"] / reviewed if reviewed else None,
        "teacher_reviewed": reviewed,
        "over_time": [{"day": day} | values for day, values in sorted(per_day.items())],
    }


def all_metrics(session: Session, storage: Storage) -> dict[str, Any]:
    """Everything `GET /api/v1/metrics` and the metrics page show."""
    scored = session.scalar(sa.select(sa.func.count()).where(Frame.uncertainty.is_not(None)))
    return {
        "student": student_curve(session),
        "teacher": teacher_quality(session, storage),
        "review": review_figures(session),
        "queue": {"scored_frames": int(scored or 0)},
    }
