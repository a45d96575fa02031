"""Stored files that rows name but the store lost: what each is, and what restores it.

The storage layer finds a lost file out in one place (``Storage.existing`` raises MissingFile);
this module says whose file it is and how to get it back, for the readers that meet one (a
frame's image, an export, a training) and for ``weldpool doctor``, which lists them all.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import MissingFile
from app.core.models import Frame, Label, ModelVersion, Proposal
from app.storage import Storage

RESTORE = {
    "image": "upload the same image again (into any run) to restore it, or delete the frame",
    "label mask": "draw and save the frame's label again to replace it",
    "proposal mask": "run the teacher or the student on the frame again for a new proposal",
    "proposal heatmap": "run the teacher or the student on the frame again for a new proposal",
    "model version": "delete the version and train a new one",
}
"""What restores each kind of lost file (on an object store, also `weldpool storage push` from
a machine whose cache still holds it)."""


@dataclass(frozen=True)
class LostFile:
    """A row's stored file the store no longer holds."""

    kind: str  # a key of RESTORE
    owner: str  # "frame 12", "proposal 7 of frame 12", "model student-v3"
    path: str
    frame_id: int | None = None

    @property
    def restore(self) -> str:
        return RESTORE[self.kind]

    def line(self) -> str:
        return f"{self.owner}: {self.kind} {self.path} is missing; {self.restore}"


def frame_file_missing(error: MissingFile, frame_id: int, kind: str = "image") -> MissingFile:
    """A lost file said of its frame: which file of which frame, and what restores it."""
    return error.about(f"Frame {frame_id}'s {kind}", RESTORE[kind])


def frame_file(storage: Storage, path: str, frame_id: int, kind: str = "image") -> Path:
    """A frame's stored file (its image, its label's or a proposal's mask), for reading; a
    lost one is MissingFile saying which frame's file it is and what restores it."""
    try:
        return storage.existing(path)
    except MissingFile as missing:
        raise frame_file_missing(missing, frame_id, kind) from None


def _named(session: Session) -> Iterator[LostFile]:
    """Every stored file a row names, as the LostFile it would be."""
    for frame_id, path in session.execute(sa.select(Frame.id, Frame.path).order_by(Frame.id)):
        yield LostFile("image", f"frame {frame_id}", path, frame_id)
    labels = (
        sa.select(Label.frame_id, Label.mask_path)
        .where(Label.mask_path.is_not(None))
        .order_by(Label.frame_id)
    )
    for frame_id, mask_path in session.execute(labels):
        yield LostFile("label mask", f"frame {frame_id}", str(mask_path), frame_id)
    proposals = sa.select(
        Proposal.id, Proposal.frame_id, Proposal.mask_path, Proposal.heatmap_path
    ).order_by(Proposal.id)
    for proposal_id, frame_id, mask, heatmap in session.execute(proposals):
        owner = f"proposal {proposal_id} of frame {frame_id}"
        yield LostFile("proposal mask", owner, mask, frame_id)
        if heatmap:
            yield LostFile("proposal heatmap", owner, heatmap, frame_id)
    models = sa.select(ModelVersion.name, ModelVersion.checkpoint_path).where(
        ModelVersion.checkpoint_path.is_not(None)
    )
    for name, folder in session.execute(models):
        yield LostFile("model version", f"model {name}", str(folder))


def lost_files(session: Session, storage: Storage) -> list[LostFile]:
    """The stored files rows name that the store lost, frames' first (one look per file on
    home, one listing per area on an object store; nothing is read)."""
    named = list(_named(session))
    lost = storage.lost({item.path for item in named})
    return [item for item in named if item.path in lost]
