"""The review loop's logic: teacher proposals, click corrections, revisioned labels, manual
validation keypoints. Every computation is weldpool_core's; this module stores and checks."""

from __future__ import annotations

import hashlib
import io
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import sqlalchemy as sa
from numpy.typing import NDArray
from sqlalchemy.orm import Session
from sqlalchemy.orm.exc import StaleDataError

from app.config import Settings
from app.db import commit_or_conflict, utcnow
from app.errors import ConflictError, InvalidInputError, NotFoundError, PermissionDeniedError
from app.models import (
    Frame,
    FrameStatus,
    Label,
    LabelRevision,
    LabelStatus,
    Proposal,
    Role,
    Split,
    User,
    ValidationKeypoints,
)
from app.review.queue import rescore_frame
from app.storage import Storage, StoredFile
from weldpool_core.io import decode_mask_png, encode_mask_png, read_image, to_rgb8
from weldpool_core.outline import CocoMask, coco_mask, region_outlines

EmbeddingSource = Literal["memory", "disk", "computed"]

# --- artefacts ---------------------------------------------------------------------------------


def store_mask_file(storage: Storage, mask: NDArray[np.bool_]) -> StoredFile:
    """A mask as a content-addressed PNG under artefacts/ (and whether this call wrote it)."""
    data = encode_mask_png(mask)
    return storage.put(data, hashlib.sha256(data).hexdigest(), ".png", area="artefacts")


def store_mask(storage: Storage, mask: NDArray[np.bool_]) -> str:
    """A mask as a content-addressed PNG under artefacts/; returns its relative path."""
    return store_mask_file(storage, mask).path


def _masks_in_use(session: Session, paths: list[str]) -> set[str]:
    """Which of ``paths`` a committed label revision or proposal names."""
    used = set(
        session.scalars(
            sa.select(LabelRevision.mask_path).where(LabelRevision.mask_path.in_(paths))
        )
    )
    used |= set(session.scalars(sa.select(Proposal.mask_path).where(Proposal.mask_path.in_(paths))))
    return {p for p in used if p}


def store_heatmap_file(storage: Storage, heatmap: NDArray[np.float32]) -> StoredFile:
    """Channel 0 of Algorithm 1's array (the mask is stored apart) as compressed float16."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, heatmap=heatmap[:, :, 0].astype(np.float16))
    data = buffer.getvalue()
    return storage.put(data, hashlib.sha256(data).hexdigest(), ".npz", area="artefacts")


class FrameDeleted(NotFoundError):
    """A job's frame was deleted while the job worked on it; nothing was recorded for it."""

    def __init__(self, frame_id: int) -> None:
        super().__init__(f"Frame {frame_id} was deleted meanwhile; nothing was recorded for it.")
        self.frame_id = frame_id


def frame_exists(session: Session, frame_id: int) -> bool:
    """Whether the frame is there now (asked on a connection of its own, so a long read
    transaction's snapshot cannot hide a deletion)."""
    with Session(session.get_bind()) as fresh:
        return fresh.scalar(sa.select(Frame.id).where(Frame.id == frame_id)) is not None


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


def lock_frame(session: Session, frame_id: int) -> None:
    """Lock the frame's row until the commit (PostgreSQL; a deletion then waits for it), or
    raise FrameDeleted when it is gone."""
    locked = sa.select(Frame.id).where(Frame.id == frame_id).with_for_update()
    if session.execute(locked).first() is None:
        raise FrameDeleted(frame_id)


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


def load_mask(storage: Storage, path: str) -> NDArray[np.bool_]:
    return decode_mask_png(storage.absolute(path).read_bytes())


def load_heatmap(storage: Storage, proposal: Proposal) -> NDArray[np.float32]:
    """The H×W×2 array (heatmap, mask) of a proposal, as Algorithm 1 returned it."""
    mask = load_mask(storage, proposal.mask_path).astype(np.float32)
    if proposal.heatmap_path is None:
        return np.stack([np.zeros_like(mask), mask], axis=2)
    with np.load(storage.absolute(proposal.heatmap_path)) as data:
        heat = data["heatmap"].astype(np.float32)
    return np.stack([heat, mask], axis=2)


def frame_rgb(storage: Storage, frame: Frame) -> NDArray[np.uint8]:
    """The frame as the models see it (RGB uint8, 16-bit stretched)."""
    return to_rgb8(read_image(storage.absolute(frame.path)))


# --- proposals ---------------------------------------------------------------------------------


def has_proposal(session: Session, frame_id: int, model_id: str) -> bool:
    return (
        session.scalar(
            sa.select(Proposal.id).where(
                Proposal.frame_id == frame_id, Proposal.model_id == model_id
            )
        )
        is not None
    )


def record_teacher_proposal(
    session: Session,
    storage: Storage,
    frame: Frame,
    result: Any,
    model_id: str,
    job_id: int | None,
    weights: Mapping[str, float],
) -> Proposal:
    """Store a TeacherResult as the frame's newest proposal, with the frame's DINO descriptor
    and its uncertainty re-scored; FrameDeleted when the frame went meanwhile."""
    with writing_for_frame(session, storage, frame.id) as write:
        proposal = Proposal(
            frame_id=frame.id,
            source="teacher",
            model_id=model_id,
            job_id=job_id,
            mask_path=write.mask(result.mask),
            heatmap_path=write.heatmap(result.heatmap) if result.heatmap is not None else None,
            keypoints=result.keypoints,
            prompts=result.prompts.as_dict(),
            scores={
                "sam2_iou": result.score,
                "object_score": result.object_score,
                "prompt_stability": result.prompt_stability,
                "mask_fraction": float(result.mask.mean()),
                "warning": result.warning,
                "keypoint_rules": result.keypoint_rules,
            },
            timings=result.timings,
        )
        session.add(proposal)
        if frame.status == FrameStatus.new:
            frame.status = FrameStatus.proposed
        frame.descriptor = [round(float(v), 5) for v in result.attention.cls]
        frame.teacher_error = None
        session.flush()
        rescore_frame(session, frame, weights)
    return proposal


def frames_for_run(
    session: Session, frame_ids: list[int] | None, sequence_id: int | None
) -> list[int]:
    """The frames a teacher run covers: the given ids (all must exist) or a whole sequence."""
    if frame_ids:
        found = set(session.scalars(sa.select(Frame.id).where(Frame.id.in_(frame_ids))))
        missing = sorted(set(frame_ids) - found)
        if missing:
            raise NotFoundError(f"There is no frame {missing[0]}.")
        return list(dict.fromkeys(frame_ids))
    if sequence_id is not None:
        ids = list(
            session.scalars(
                sa.select(Frame.id).where(Frame.sequence_id == sequence_id).order_by(Frame.id)
            )
        )
        if not ids:
            raise InvalidInputError(f"Sequence {sequence_id} has no frames.")
        return ids
    raise InvalidInputError("Give frame_ids or a sequence_id.")


# --- click corrections -------------------------------------------------------------------------


@dataclass(frozen=True)
class Segmentation:
    """The answer to a click: the best mask and how it was made."""

    mask: NDArray[np.bool_]
    score: float
    scores: list[float]
    elapsed_ms: float
    embedding: EmbeddingSource


def _mask_prompt(mask: NDArray[np.bool_]) -> NDArray[np.float32]:
    """A binary mask as SAM2's 256×256 mask-logit input (±8 by the covered fraction)."""
    import cv2

    fraction = cv2.resize(mask.astype(np.float32), (256, 256), interpolation=cv2.INTER_AREA)
    return (fraction * 16.0 - 8.0).astype(np.float32)


def segment(
    storage: Storage,
    settings: Settings,
    frame: Frame,
    points: list[tuple[float, float, bool]],
    box: tuple[float, float, float, float] | None,
    previous_mask: NDArray[np.bool_] | None,
) -> Segmentation:
    """A new mask for ``frame`` from clicks, a box and/or a previous mask, using the frame's
    cached SAM2 embedding (computed and cached on first use)."""
    from app.review import runtime
    from weldpool_core.teacher.cache import cached_embedding
    from weldpool_core.teacher.sam2 import Prompts

    start = time.perf_counter()
    for x, y, _ in points:
        if not (0 <= x <= frame.width and 0 <= y <= frame.height):
            raise InvalidInputError(
                f"The point ({x:g}, {y:g}) lies outside the {frame.width}×{frame.height} frame."
            )
    if previous_mask is not None and previous_mask.shape != (frame.height, frame.width):
        raise InvalidInputError("The previous mask must have the frame's size.")
    prompts = Prompts(
        tuple((x, y) for x, y, _ in points),
        tuple(1 if positive else 0 for _, _, positive in points),
        box,
        _mask_prompt(previous_mask) if previous_mask is not None else None,
    )
    if prompts.empty:
        raise InvalidInputError("Give at least one point, a box or a previous mask.")
    predictor = runtime.sam2_predictor(settings)
    embedding, source = cached_embedding(
        predictor,
        runtime.embedding_cache(settings),
        frame.sha256,
        lambda: frame_rgb(storage, frame),
        (frame.height, frame.width),
    )
    prediction = predictor.predict(embedding, prompts)
    return Segmentation(
        mask=prediction.mask,
        score=prediction.score,
        scores=[float(s) for s in prediction.scores],
        elapsed_ms=(time.perf_counter() - start) * 1000,
        embedding=source,
    )


# --- labels ------------------------------------------------------------------------------------


def current_label(session: Session, frame_id: int) -> Label | None:
    return session.scalar(sa.select(Label).where(Label.frame_id == frame_id))


def _keypoints_for(mask: NDArray[np.bool_]) -> list[list[float]]:
    from weldpool_core.heatmap import heatmap_from_mask

    try:
        result = heatmap_from_mask(mask)
    except InvalidInputError as exc:
        raise InvalidInputError(
            f"Keypoints cannot be computed for this mask: {exc.message}"
        ) from None
    return [[float(x), float(y)] for x, y in np.asarray(result.keypoints)]


def check_keypoints(frame: Frame, keypoints: list[list[float]]) -> list[list[float]]:
    """Keypoints as [[x, y], …] inside the frame, or a clear error."""
    for point in keypoints:
        if len(point) != 2:
            raise InvalidInputError("Each keypoint is [x, y].")
        x, y = point
        if not (0 <= x <= frame.width and 0 <= y <= frame.height):
            raise InvalidInputError(
                f"The keypoint ({x:g}, {y:g}) lies outside the {frame.width}×{frame.height} frame."
            )
    return [[float(x), float(y)] for x, y in keypoints]


def save_label(
    session: Session,
    storage: Storage,
    frame: Frame,
    user: User,
    *,
    status: LabelStatus,
    base_revision: int,
    mask_png: bytes | None,
    keypoints: list[list[float]] | None,
    proposal_id: int | None = None,
) -> Label:
    """Accept, correct or reject a frame's proposal, guarded by the label's revision.

    ``base_revision`` is the revision the client saw (0 when there was no label); a stale one
    raises ConflictError with the current revision. Every change is kept in the history.
    Keypoints of a corrected mask are recomputed by Algorithm 1 unless given. The label records
    the proposal it started from (``proposal_id``, default the one the policy shows) and whether
    its mask differs from that proposal's.
    """
    from app.review.policy import pick

    frame_id = frame.id
    lock_frame(session, frame_id)  # a deletion now waits for this save (PostgreSQL)
    if (
        status in (LabelStatus.accepted, LabelStatus.rejected)
        and user.role.rank < Role.reviewer.rank
    ):
        raise PermissionDeniedError(
            f"Only reviewers may mark a label {status.value}; save it as corrected instead."
        )
    proposal = pick(session, storage, frame.id, proposal_id=proposal_id)
    mask: NDArray[np.bool_] | None = None
    mask_path: str | None = None
    if status == LabelStatus.rejected:
        keypoints = None
    elif mask_png is not None:
        mask = decode_mask_png(mask_png)
        if mask.shape != (frame.height, frame.width):
            raise InvalidInputError(
                f"The mask is {mask.shape[1]}×{mask.shape[0]}; the frame is "
                f"{frame.width}×{frame.height}."
            )
        if not mask.any():
            raise InvalidInputError("The mask is empty; reject the frame instead.")
        keypoints = check_keypoints(frame, keypoints) if keypoints else _keypoints_for(mask)
    elif proposal is not None:
        mask_path = proposal.mask_path
        keypoints = check_keypoints(frame, keypoints) if keypoints else proposal.keypoints
    else:
        raise InvalidInputError(
            "The frame has no proposal to accept; send a mask_png or run the teacher first."
        )

    mask_changed: bool | None = None
    if mask is not None:
        mask_changed = proposal is None or not np.array_equal(
            mask, load_mask(storage, proposal.mask_path)
        )
    elif mask_path is not None:
        mask_changed = False
    label = current_label(session, frame.id)
    current = label.revision if label else 0
    if base_revision != current:  # refused before anything is written
        raise stale_revision(session, frame.id)
    stored: StoredFile | None = None
    coco: CocoMask | None = None
    outlines: list[Any] | None = None
    if mask is not None:
        coco, outlines = coco_mask(mask), region_outlines(mask)
        stored = store_mask_file(storage, mask)
        mask_path = stored.path
    elif mask_path is not None:
        accepted = load_mask(storage, mask_path)
        coco, outlines = coco_mask(accepted), region_outlines(accepted)
    values = {
        "status": status,
        "mask_path": mask_path,
        "mask_rle": coco.rle if coco else None,
        "mask_area": coco.area if coco else None,
        "mask_bbox": coco.bbox if coco else None,
        "mask_outlines": outlines,
        "keypoints": keypoints,
        "proposal_id": proposal.id if proposal else None,
        "mask_changed": mask_changed,
        "updated_by_id": user.id,
        "updated_at": utcnow(),
    }
    try:
        if label is None:
            label = Label(frame_id=frame.id, revision=1, **values)
            session.add(label)
            session.flush()
        else:
            updated = session.execute(
                sa.update(Label)
                .where(Label.frame_id == frame.id, Label.revision == base_revision)
                .values(revision=base_revision + 1, **values)
            )
            if updated.rowcount != 1:  # type: ignore[attr-defined]
                raise stale_revision(session, frame.id)
        session.add(
            LabelRevision(
                frame_id=frame.id,
                revision=base_revision + 1,
                status=status,
                mask_path=mask_path,
                keypoints=keypoints,
                proposal_id=values["proposal_id"],
                mask_changed=mask_changed,
                user_id=user.id,
            )
        )
        frame.status = FrameStatus(status.value)
        session.commit()
    except BaseException as exc:
        session.rollback()
        if stored is not None:
            storage.discard([stored], in_use=_masks_in_use(session, [stored.path]))
        if isinstance(exc, sa.exc.IntegrityError | StaleDataError):
            if not frame_exists(session, frame_id):
                raise FrameDeleted(frame_id) from None
            raise stale_revision(session, frame_id) from None  # two first labels at once
        raise
    try:
        session.refresh(label)
    except sa.exc.InvalidRequestError:  # saved, then deleted with its frame at once
        raise FrameDeleted(frame_id) from None
    return label


class StaleRevision(ConflictError):
    """The label changed since the client read it: who changed it, and its revision now."""

    def __init__(self, current: int, by: str | None = None) -> None:
        who = f"by {by}" if by else "by someone else"
        super().__init__(
            f"The label was changed {who} (now at revision {current}); reload it "
            "and apply your change again, or overwrite with base_revision "
            f"{current}."
        )
        self.current = current
        self.extra = {"revision": current, "updated_by": by}


def stale_revision(session: Session, frame_id: int) -> StaleRevision:
    """The conflict for a stale save, naming the label's current revision and its author."""
    row = session.execute(
        sa.select(Label.revision, User.username)
        .outerjoin(User, User.id == Label.updated_by_id)
        .where(Label.frame_id == frame_id)
    ).first()
    return StaleRevision(row[0], row[1]) if row else StaleRevision(0)


def current_revision(session: Session, frame_id: int) -> int:
    return session.scalar(sa.select(Label.revision).where(Label.frame_id == frame_id)) or 0


def label_history(session: Session, frame_id: int) -> list[tuple[LabelRevision, str | None]]:
    """Every revision of a frame's label, oldest first, with the user's name."""
    rows = session.execute(
        sa.select(LabelRevision, User.username)
        .outerjoin(User, User.id == LabelRevision.user_id)
        .where(LabelRevision.frame_id == frame_id)
        .order_by(LabelRevision.revision)
    )
    return [(revision, name) for revision, name in rows]


# --- validation keypoints ----------------------------------------------------------------------


def save_validation_keypoints(
    session: Session, frame: Frame, user: User, keypoints: list[list[float]]
) -> ValidationKeypoints:
    """Manual keypoints; the frame moves to the validation split and never trains the student."""
    if not keypoints:
        raise InvalidInputError("Give at least one keypoint.")
    points = check_keypoints(frame, keypoints)
    lock_frame(session, frame.id)
    row = session.scalar(
        sa.select(ValidationKeypoints).where(ValidationKeypoints.frame_id == frame.id)
    )
    if row is None:
        row = ValidationKeypoints(frame_id=frame.id, keypoints=points, user_id=user.id)
        session.add(row)
    else:
        row.keypoints, row.user_id, row.updated_at = points, user.id, utcnow()
    frame.split = Split.validation
    commit_or_conflict(
        session,
        f"Someone else saved validation keypoints of frame {frame.id} at the same moment; "
        "reload them and save again.",
    )
    return row


def get_validation_keypoints(session: Session, frame_id: int) -> ValidationKeypoints:
    row = session.scalar(
        sa.select(ValidationKeypoints).where(ValidationKeypoints.frame_id == frame_id)
    )
    if row is None:
        raise NotFoundError(f"Frame {frame_id} has no validation keypoints.")
    return row
