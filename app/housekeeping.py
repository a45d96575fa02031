"""Housekeeping: the file collector (at start-up and in a thread of the web process), and
training state and exports that are no longer needed."""

from __future__ import annotations

from pathlib import Path

import sqlalchemy as sa
import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.models import STORED_PATH_COLUMNS, ModelVersion
from app.periodic import Periodic
from app.storage import EXPORTS_DIR, Storage

SWEPT_AREAS = ("frames", "videos", "artefacts")
log = structlog.get_logger(__name__)


def sweep_orphan_files(
    session: Session, storage: Storage, older_than_s: float | None = None
) -> int:
    """Remove stored files (frames, videos, masks, heatmaps) that no committed row names and
    nobody claimed within the grace period (or ``older_than_s``)."""
    known: set[str] = set()
    for column in STORED_PATH_COLUMNS:
        known.update(p for p in session.scalars(sa.select(column).distinct()) if p)
    return len(storage.sweep_orphans(SWEPT_AREAS, known, older_than_s))


FIRST_SWEEP_AFTER_S = 30.0
"""The web process answers first: its first sweep (a listing of the store) waits this long."""


class FileCollector(Periodic):
    """Sweeps the store three times per grace period, in a thread of the web process: files
    whose claim was too fresh when their rows were deleted, and files a failed write left. The
    first pass, a little after start, also prunes the training state recorded versions no
    longer need: ``serve`` answers before any of it."""

    def __init__(self, session_factory: sessionmaker[Session], storage: Storage) -> None:
        self.session_factory, self.storage = session_factory, storage
        self._first = True
        interval = storage.grace_s / 3
        super().__init__("files", interval, self.sweep, min(interval, FIRST_SWEEP_AFTER_S))

    def sweep(self) -> int:
        with self.session_factory() as session:
            if self._first:
                self._first = False
                freed = prune_training_state(session, self.storage.home)
                if freed:
                    log.info("files.training_state_pruned", mb=round(freed / 2**20))
            removed = sweep_orphan_files(session, self.storage)
        if removed:
            log.info("files.collected", removed=removed)
        return removed


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


def prune_old_files(folder: Path, older_than_s: float = 86_400.0, pattern: str = "*") -> int:
    """Remove the files in ``folder`` older than a day: export zips (an export job's download
    is kept that long) and uploaded imports a dead worker left."""
    import time

    removed = 0
    for path in folder.glob(pattern):
        if path.is_file() and time.time() - path.stat().st_mtime > older_than_s:
            path.unlink(missing_ok=True)
            removed += 1
    return removed


def prune_shared(
    storage: Storage, area: str, older_than_s: float = 86_400.0, pattern: str = "*"
) -> int:
    """Remove the files of a shared area (export zips, uploaded imports) older than a day,
    here and in the object store."""
    removed = prune_old_files(storage.home / area, older_than_s, pattern)
    return removed + storage.prune_published(area, older_than_s)


def prune_exports(storage: Storage, older_than_s: float = 86_400.0) -> int:
    """Remove export zips older than a day (an export job's download is kept that long)."""
    return prune_shared(storage, EXPORTS_DIR, older_than_s, "*.zip")
