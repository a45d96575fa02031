"""Housekeeping at start-up: files that a crash left without a row, and training state that
recorded versions no longer need."""

from __future__ import annotations

from pathlib import Path

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.models import STORED_PATH_COLUMNS, ModelVersion
from app.storage import Storage

SWEPT_AREAS = ("frames", "videos", "artefacts")


def sweep_orphan_files(session: Session, storage: Storage, older_than_s: float = 3600.0) -> int:
    """Remove stored files (frames, videos, masks, heatmaps) that no row names."""
    known: set[str] = set()
    for column in STORED_PATH_COLUMNS:
        known.update(p for p in session.scalars(sa.select(column).distinct()) if p)
    return len(storage.sweep_orphans(SWEPT_AREAS, known, older_than_s))


def prune_training_state(session: Session, home: Path) -> int:
    """Remove the resumable training state of every recorded student version (versions made
    before the training job pruned it itself); returns the bytes freed."""
    from weldpool_core.student.checkpoint import prune_state

    freed = 0
    for relative in session.scalars(sa.select(ModelVersion.checkpoint_path)):
        if not relative:
            continue
        folder = (home / relative).resolve()
        if folder.is_relative_to(home.resolve()) and folder.is_dir():
            freed += prune_state(folder)
    return freed


def prune_exports(home: Path, older_than_s: float = 86_400.0) -> int:
    """Remove export zips older than a day (an export job's download is kept that long)."""
    import time

    from app.review.export import EXPORTS_DIR

    removed = 0
    for path in (home / EXPORTS_DIR).glob("*.zip"):
        if time.time() - path.stat().st_mtime > older_than_s:
            path.unlink(missing_ok=True)
            removed += 1
    return removed
