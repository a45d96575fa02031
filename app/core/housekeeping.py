"""Housekeeping: the file collector (in a thread of the web process), and training state and
exports that are no longer needed.

The collector works from the rows that changed: a transaction that deletes rows naming files
(a frame, a run, a replaced proposal) writes their paths to ``doomed_files`` (``doom``); each
pass looks at those files only (``collect_doomed``), removing those no row names any more once
nobody claimed them for the grace period. A full sweep, which lists the store and reads every
stored path, runs once a day for what a crash between a file's write and its row's commit
left."""

from __future__ import annotations

from pathlib import Path

import sqlalchemy as sa
import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.core.db import utcnow
from app.core.models import STORED_PATH_COLUMNS, DoomedFile, ModelVersion
from app.core.periodic import Periodic
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


_CHUNK = 500


def still_used(session: Session, paths: set[str]) -> set[str]:
    """Those of ``paths`` that a committed row still names (content is shared by hash)."""
    used: set[str] = set()
    candidates = sorted(paths)
    for column in STORED_PATH_COLUMNS:
        for start in range(0, len(candidates), _CHUNK):
            chunk = candidates[start : start + _CHUNK]
            used.update(p for p in session.scalars(sa.select(column).where(column.in_(chunk))) if p)
    return used


def doom(session: Session, paths: set[str]) -> None:
    """Record, in the caller's transaction, files whose naming rows it deletes: the collector
    looks at them (a path recorded twice is kept once)."""
    known: set[str] = set()
    candidates = sorted(p for p in paths if p)
    for start in range(0, len(candidates), _CHUNK):
        chunk = candidates[start : start + _CHUNK]
        known.update(session.scalars(sa.select(DoomedFile.path).where(DoomedFile.path.in_(chunk))))
    fresh = [{"path": p, "since": utcnow()} for p in candidates if p not in known]
    if fresh:
        session.execute(sa.insert(DoomedFile), fresh)


def collect_doomed(session: Session, storage: Storage, paths: set[str] | None = None) -> list[str]:
    """Remove the doomed files (``paths`` of them, or all) that no row names and nobody claimed
    for the grace period, and forget them and those in use again; a file claimed too recently
    stays doomed for a later pass. Returns the removed paths."""
    query = sa.select(DoomedFile.path)
    if paths is not None:
        query = query.where(DoomedFile.path.in_(sorted(paths)))
    doomed = set(session.scalars(query))
    if not doomed:
        return []
    in_use = still_used(session, doomed)
    removed = storage.collect(doomed, in_use)
    settled = sorted(in_use | set(removed))
    for start in range(0, len(settled), _CHUNK):
        chunk = settled[start : start + _CHUNK]
        session.execute(sa.delete(DoomedFile).where(DoomedFile.path.in_(chunk)))
    session.commit()
    return removed


FIRST_SWEEP_AFTER_S = 30.0
"""The web process answers first: its first pass waits this long."""
FULL_SWEEP_EVERY_S = 86_400.0
"""How often the collector lists the whole store (for what a crash left unrecorded)."""


class FileCollector(Periodic):
    """Collects doomed files three times per grace period, in a thread of the web process, and
    lists the whole store once a day (not at start: a crash's leftovers wait a day). The first
    pass, a little after start, also prunes the training state recorded versions no longer
    need: ``serve`` answers before any of it."""

    def __init__(self, session_factory: sessionmaker[Session], storage: Storage) -> None:
        import time

        self.session_factory, self.storage = session_factory, storage
        self._first = True
        self._next_full = time.monotonic() + FULL_SWEEP_EVERY_S
        interval = storage.grace_s / 3
        super().__init__("files", interval, self.sweep, min(interval, FIRST_SWEEP_AFTER_S))

    def sweep(self) -> int:
        import time

        with self.session_factory() as session:
            if self._first:
                self._first = False
                freed = prune_training_state(session, self.storage)
                if freed:
                    log.info("files.training_state_pruned", mb=round(freed / 2**20))
            removed = len(collect_doomed(session, self.storage))
            if time.monotonic() >= self._next_full:
                self._next_full = time.monotonic() + FULL_SWEEP_EVERY_S
                removed += sweep_orphan_files(session, self.storage)
        if removed:
            log.info("files.collected", removed=removed)
        return removed


def prune_training_state(session: Session, storage: Storage) -> int:
    """Remove the resumable training state of every recorded student version (versions made
    before the training job pruned it itself); returns the bytes freed."""
    from weldpool_core.student.checkpoint import prune_state

    freed = 0
    for relative in session.scalars(sa.select(ModelVersion.checkpoint_path)):
        if not relative:
            continue
        try:
            folder = storage.local(relative)
        except ValueError:  # a path outside home is never touched
            continue
        if folder.is_dir():
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
    removed = prune_old_files(storage.local(area), older_than_s, pattern)
    return removed + storage.prune_published(area, older_than_s)


def prune_exports(storage: Storage, older_than_s: float = 86_400.0) -> int:
    """Remove export zips older than a day (an export job's download is kept that long)."""
    return prune_shared(storage, EXPORTS_DIR, older_than_s, "*.zip")
