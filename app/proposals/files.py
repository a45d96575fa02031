"""A proposal's files and the guarded write of one frame's rows and files.

Masks are content-addressed PNGs and heatmaps compressed float16 arrays under ``artefacts/``;
``writing_for_frame`` commits a job's rows for one frame together with the files it stored,
or rolls both back, while the frame may be deleted meanwhile.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import sqlalchemy as sa
from sqlalchemy.orm import Session
from sqlalchemy.orm.exc import StaleDataError

from app.core.frame_rows import FrameDeleted, frame_exists, lock_frame
from app.core.models import LabelRevision, OverlapLabel, Proposal
from app.storage import Storage, StoredFile
from weldpool_core.io import encode_mask_png

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np


def store_mask_file(storage: Storage, mask: NDArray[np.bool_]) -> StoredFile:
    """A mask as a content-addressed PNG under artefacts/ (and whether this call wrote it)."""
    data = encode_mask_png(mask)
    return storage.put(data, hashlib.sha256(data).hexdigest(), ".png", area="artefacts")


def store_mask(storage: Storage, mask: NDArray[np.bool_]) -> str:
    """A mask as a content-addressed PNG under artefacts/; returns its relative path."""
    return store_mask_file(storage, mask).path


def masks_in_use(session: Session, paths: list[str]) -> set[str]:
    """Which of ``paths`` a committed label revision, proposal or annotator's own label names."""
    used = set(
        session.scalars(
            sa.select(LabelRevision.mask_path).where(LabelRevision.mask_path.in_(paths))
        )
    )
    used |= set(session.scalars(sa.select(Proposal.mask_path).where(Proposal.mask_path.in_(paths))))
    used |= set(
        session.scalars(sa.select(OverlapLabel.mask_path).where(OverlapLabel.mask_path.in_(paths)))
    )
    return {p for p in used if p}


def store_heatmap_file(storage: Storage, heatmap: NDArray[np.float32]) -> StoredFile:
    """Channel 0 of Algorithm 1's array (the mask is stored apart) as compressed float16."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, heatmap=heatmap[:, :, 0].astype(np.float16))
    data = buffer.getvalue()
    return storage.put(data, hashlib.sha256(data).hexdigest(), ".npz", area="artefacts")


@dataclass
class FrameWrite:
    """The files one guarded write for a frame stores (``writing_for_frame``)."""

    storage: Storage
    files: list[StoredFile] = field(default_factory=list)

    def mask(self, mask: NDArray[np.bool_]) -> str:
        self.files.append(store_mask_file(self.storage, mask))
        return self.files[-1].path

    def heatmap(self, heatmap: NDArray[np.float32]) -> str:
        self.files.append(store_heatmap_file(self.storage, heatmap))
        return self.files[-1].path


@contextmanager
def writing_for_frame(session: Session, storage: Storage, frame_id: int) -> Iterator[FrameWrite]:
    """Rows and files a job records for one frame, committed at the end of the block, while
    the frame may be deleted: its row is locked first (PostgreSQL; a deletion then waits for
    the commit), and a frame deleted before (or, on SQLite, a commit that loses to the
    deletion) ends in FrameDeleted. On any failure the rows are rolled back and the files this
    write created are discarded (unless another writer claimed them since)."""
    write = FrameWrite(storage)
    try:
        lock_frame(session, frame_id)
        yield write
        session.commit()
    except BaseException as exc:
        session.rollback()
        storage.discard(write.files)
        lost = isinstance(exc, sa.exc.IntegrityError | StaleDataError)
        if lost and not frame_exists(session, frame_id):
            raise FrameDeleted(frame_id) from None
        raise
