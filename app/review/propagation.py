"""Propagation through a weld run: reviewed masks carried frame by frame by SAM2's video model
(``weldpool_core.teacher.propagate``), one ``propagated`` proposal per frame.

- Prompts are the reviewed masks (accepted or corrected labels) of the frames it starts from;
  the run is walked in frame order (frame index, then upload order).
- Image features come from the teacher's embedding cache, so frames the teacher has seen cost
  memory attention and decoding only.
- Each frame's proposal is written in its own transaction, replacing the frame's earlier
  propagated proposals (never a label, nor a proposal a label started from): a cancelled run
  leaves whole proposals only.
- Confidence is SAM2's object probability times its predicted IoU; a frame below the threshold
  is flagged, and a pass stops after ``STOP_AFTER`` such frames in a row, where the reviewer
  should prompt again (the job says where).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, cast

import sqlalchemy as sa
from sqlalchemy.orm import Session
from sqlalchemy.orm.exc import ObjectDeletedError

from app.core.errors import InvalidInputError
from app.core.frame_rows import FrameDeleted, frame_exists
from app.core.models import Frame, Label, LabelStatus, Proposal
from app.frames.listing import run_frames
from app.jobs.registry import counted
from app.proposals.record import PROPAGATED, record_proposal
from app.storage import Storage
from app.storage.pixels import frame_rgb, load_mask
from weldpool_core.errors import InvalidInputError as CoreInvalidInput
from weldpool_core.heatmap import heatmap_from_mask
from weldpool_core.teacher.passes import Direction, passes

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

SOURCE = PROPAGATED
STOP_AFTER = 3
"""Frames in a row under the confidence threshold after which a pass stops."""


def model_id(sam2_ref: str) -> str:
    """What propagated proposals name as their model: SAM2's video model and its weights."""
    return f"sam2-video:{sam2_ref.rstrip('/').rsplit('/', 1)[-1]}"


def check_prompts(session: Session, sequence_id: int, frame_ids: list[int]) -> None:
    """Every frame to start from belongs to the run and has a reviewed mask."""
    if not frame_ids:
        raise InvalidInputError("Give at least one reviewed frame to propagate from.")
    rows = dict(
        session.execute(sa.select(Frame.id, Frame.sequence_id).where(Frame.id.in_(frame_ids))).all()
    )
    for frame_id in frame_ids:
        if rows.get(frame_id) != sequence_id:
            raise InvalidInputError(f"Frame {frame_id} is not a frame of weld run {sequence_id}.")
    reviewed = set(
        session.scalars(
            sa.select(Label.frame_id).where(
                Label.frame_id.in_(frame_ids),
                Label.status.in_([LabelStatus.accepted, LabelStatus.corrected]),
                Label.mask_path.is_not(None),
            )
        )
    )
    for frame_id in frame_ids:
        if frame_id not in reviewed:
            raise InvalidInputError(
                f"Frame {frame_id} has no reviewed mask to start from; accept or correct it first."
            )


def record(
    session: Session,
    storage: Storage,
    frame: Frame,
    mask: NDArray[np.bool_],
    scores: dict[str, Any],
    model_id: str,
    job_id: int | None,
    weights: Mapping[str, float],
) -> Proposal:
    """Store one propagated mask as the frame's proposal, replacing its earlier ones; its
    confidence joins the frame's queue score."""
    keypoints: list[list[float]] = []
    heatmap = None
    try:
        result = heatmap_from_mask(mask)
    except CoreInvalidInput as exc:
        scores = scores | {"warning": f"No keypoints: {exc.message}"}
    else:
        keypoints = [[float(x), float(y)] for x, y in np.asarray(result.keypoints)]
        heatmap = result.heatmap
    return record_proposal(
        session,
        storage,
        frame,
        source=PROPAGATED,
        model_id=model_id,
        mask=mask,
        heatmap=heatmap,
        keypoints=keypoints,
        scores=scores,
        weights=weights,
        job_id=job_id,
        prompts={"from_frame_id": scores["from_frame_id"]},
        replace_earlier=True,
    )


def _prompts(
    session: Session, storage: Storage, frames: list[Frame], from_frame_ids: list[int]
) -> dict[int, NDArray[np.bool_]]:
    """The reviewed masks to start from, by their place in the walk."""
    position = {frame.id: i for i, frame in enumerate(frames)}
    labels = {
        label.frame_id: label
        for label in session.scalars(sa.select(Label).where(Label.frame_id.in_(from_frame_ids)))
    }
    return {
        position[i]: load_mask(storage, labels[i].mask_path)  # type: ignore[arg-type]
        for i in from_frame_ids
    }


def _until(indices: list[int | None], until_frame_index: int | None) -> int | None:
    """The walk's place nearest the frame index a one-way pass stops at (None: to the end)."""
    if until_frame_index is None:
        return None
    order = [index if index is not None else i for i, index in enumerate(indices)]
    return min(range(len(order)), key=lambda i: abs(order[i] - until_frame_index))


class _Walk:
    """One propagation's bookkeeping: where each pass stopped, what was written, flagged
    (under the threshold) or found deleted."""

    def __init__(self, session: Session, frames: list[Frame], threshold: float) -> None:
        self.session, self.frames, self.threshold = session, frames, threshold
        self.ids = [frame.id for frame in frames]  # read now: a rollback expires the rows
        self.indices = [frame.frame_index for frame in frames]
        self.low_streak = {False: 0, True: 0}
        self.stopped: list[dict[str, Any]] = []
        self.flagged: list[int] = []
        self.deleted: list[int] = []
        self.written = 0

    def keep_going(self, item: Any, reverse: bool) -> bool:
        """False once ``STOP_AFTER`` frames in a row of this pass fell under the threshold."""
        low = item.confidence < self.threshold
        self.low_streak[reverse] = self.low_streak[reverse] + 1 if low else 0
        if self.low_streak[reverse] < STOP_AFTER:
            return True
        self.stopped.append(
            {
                "direction": "backward" if reverse else "forward",
                "frame_id": self.ids[item.index],
                "frame_index": self.indices[item.index],
            }
        )
        return False

    def embedding_of(self, embedding: Callable[[Frame], Any]) -> Callable[[int], Any]:
        """The walk's place → the frame's embedding, or a one-sentence error when the frame
        was deleted meanwhile."""

        def embed(i: int) -> Any:
            try:
                return embedding(self.frames[i])
            except (FileNotFoundError, ObjectDeletedError):
                if frame_exists(self.session, self.ids[i]):
                    raise
                raise InvalidInputError(
                    f"Frame #{self.ids[i]} of the run was deleted while propagating; "
                    f"{counted(self.written, 'proposal')} had been recorded. Propagate again."
                ) from None

        return embed

    def scores(self, item: Any) -> dict[str, Any]:
        return {
            "confidence": item.confidence,
            "object_score": item.object_score,
            "sam2_iou": item.iou,
            "from_frame_id": self.ids[item.source_index],
            "low_confidence": item.confidence < self.threshold,
        }


def propagate_run(
    session: Session,
    storage: Storage,
    propagator: Any,
    embedding: Callable[[Frame], Any],
    *,
    sequence_id: int,
    from_frame_ids: list[int],
    direction: str,
    until_frame_index: int | None,
    threshold: float,
    model_id: str,
    job_id: int | None,
    progress: Callable[[float, str], None],
    weights: Mapping[str, float],
) -> dict[str, Any]:
    """Propagate through the run (module doc); returns what was written and where it stopped."""
    check_prompts(session, sequence_id, from_frame_ids)
    frames = run_frames(session, sequence_id)
    prompts = _prompts(session, storage, frames, from_frame_ids)
    walk = _Walk(session, frames, threshold)
    until = _until(walk.indices, until_frame_index)
    plan = passes(len(frames), prompts, cast(Direction, direction), until)
    planned = len([i for order, _ in plan for i in order if i not in prompts])
    embed = walk.embedding_of(embedding)
    for item in propagator.propagate(
        len(frames), prompts, embed, direction, until, keep_going=walk.keep_going
    ):
        frame_id, scores = walk.ids[item.index], walk.scores(item)
        try:
            record(
                session, storage, frames[item.index], item.mask, scores, model_id, job_id, weights
            )
        except (FrameDeleted, ObjectDeletedError):  # gone before, or while, it was written
            session.rollback()
            walk.deleted.append(frame_id)
            continue
        if scores["low_confidence"]:
            walk.flagged.append(frame_id)
        walk.written += 1
        progress(min(1.0, walk.written / max(1, planned)), f"{walk.written} of {planned} frames")
    return {
        "deleted_frame_ids": walk.deleted,
        "proposed": walk.written,
        "low_confidence_frame_ids": walk.flagged,
        "stopped": walk.stopped,
        "from_frame_ids": from_frame_ids,
        "model_id": model_id,
    }


def frame_embedding(storage: Storage, predictor: Any, cache: Any) -> Callable[[Frame], Any]:
    """A frame's SAM2 image embedding through the one cache seam (computed once, then reused
    by clicks, the teacher and later propagations)."""
    from weldpool_core.teacher.cache import cached_embedding

    def embed(frame: Frame) -> Any:
        embedding, _ = cached_embedding(
            predictor,
            cache,
            frame.sha256,
            lambda: frame_rgb(storage, frame),
            (frame.height, frame.width),
        )
        return embedding

    return embed
