"""Housekeeping at start-up: files that a crash left without a row."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.models import Frame, Label, LabelRevision, Proposal, Video
from app.storage import Storage

SWEPT_AREAS = ("frames", "videos", "artefacts")


def sweep_orphan_files(session: Session, storage: Storage, older_than_s: float = 3600.0) -> int:
    """Remove stored files (frames, videos, masks, heatmaps) that no row names."""
    columns = (
        Frame.path,
        Video.path,
        Proposal.mask_path,
        Proposal.heatmap_path,
        Label.mask_path,
        LabelRevision.mask_path,
    )
    known: set[str] = set()
    for column in columns:
        known.update(p for p in session.scalars(sa.select(column).distinct()) if p)
    return len(storage.sweep_orphans(SWEPT_AREAS, known, older_than_s))
