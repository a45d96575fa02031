"""The review queue: each frame's uncertainty from its latest proposals (the teacher's, the
student's, propagation's), and a diverse order of the queue's head (see weldpool_core.active
for the scores)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.models import Frame, Proposal
from weldpool_core.active import (
    combined_score,
    diverse_order,
    main_reason,
    propagation_components,
    teacher_components,
)

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np


def latest_teacher_proposal(session: Session, frame_id: int) -> Proposal | None:
    return _latest(session, frame_id, "teacher")


def _latest(session: Session, frame_id: int, source: str) -> Proposal | None:
    return session.scalar(
        sa.select(Proposal)
        .where(Proposal.frame_id == frame_id, Proposal.source == source)
        .order_by(Proposal.id.desc())
    )


def rescore_frame(session: Session, frame: Frame, weights: Mapping[str, float]) -> None:
    """Recompute the frame's uncertainty components, score and main reason (not committed)."""
    components: dict[str, Any] = {}
    teacher = _latest(session, frame.id, "teacher")
    if teacher is not None:
        components |= teacher_components(
            teacher.scores.get("sam2_iou"), teacher.scores.get("prompt_stability")
        )
    student = _latest(session, frame.id, "student")
    if student is not None:
        components["student_uncertainty"] = student.scores.get("uncertainty")
        components["disagreement"] = student.scores.get("disagreement")
    propagated = _latest(session, frame.id, "propagated")
    if propagated is not None:
        components |= propagation_components(propagated.scores.get("confidence"))
    frame.uncertainty_components = components or None
    frame.uncertainty = combined_score(components, weights)
    frame.uncertainty_reason = main_reason(components, weights)


def diverse_head(frames: list[Frame], trade_off: float) -> list[Frame]:
    """The queue's head reordered so that near-identical frames do not follow each other;
    frames without a DINO descriptor keep their place after those with one."""
    described = [
        f
        for f in frames
        if f.descriptor is not None and f.descriptor.size and f.uncertainty is not None
    ]
    if trade_off <= 0 or len(described) < 3:
        return frames
    scores = np.array([f.uncertainty for f in described], np.float64)
    vectors = np.stack([f.descriptor for f in described]).astype(np.float64)
    ordered = [described[i] for i in diverse_order(scores, vectors, trade_off)]
    return ordered + [f for f in frames if f not in described]
