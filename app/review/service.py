"""The review loop's logic: teacher proposals, click corrections, revisioned labels, manual
validation keypoints. Every computation is weldpool_core's; this module stores and checks."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import sqlalchemy as sa
from sqlalchemy.orm import Session
from sqlalchemy.orm.exc import StaleDataError

from app.core.config import Settings
from app.core.db import updated_one, utcnow
from app.core.errors import ConflictError, InvalidInputError, NotFoundError, PermissionDeniedError
from app.core.frame_rows import FrameDeleted, frame_exists, lock_frame
from app.core.models import (
    Frame,
    FrameStatus,
    Label,
    LabelRevision,
    LabelStatus,
    OverlapLabel,
    Proposal,
    ReviewState,
    Split,
    User,
    ValidationKeypoints,
)
from app.core.permissions import Action, may
from app.labelconfig import facets as labelfacets
from app.labelconfig import retired
from app.labelconfig import service as labelconfig
from app.labelconfig.retired import Retired
from app.proposals.files import masks_in_use, store_mask_file
from app.proposals.policy import pick
from app.storage import Storage, StoredFile
from app.storage.pixels import frame_rgb, load_mask
from app.teacher import runtime
from weldpool_core.heatmap import mask_keypoints
from weldpool_core.io import decode_mask_png
from weldpool_core.outline import mask_record

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

EmbeddingSource = Literal["memory", "disk", "shared", "computed"]

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


def stored_mask(
    session: Session,
    storage: Storage,
    frame: Frame,
    *,
    label_revision: int | None = None,
    proposal_id: int | None = None,
) -> NDArray[np.bool_]:
    """A mask of ``frame`` the server has: its label at ``label_revision`` (409 when the label
    has moved on: the page then sends what it shows), or its proposal ``proposal_id``."""
    if label_revision is not None:
        label = current_label(session, frame.id)
        if label is None or label.revision != label_revision:
            raise MovedOn(label.revision if label else 0, label_revision)
        if label.mask_path is None:
            raise InvalidInputError(
                f"Label revision {label_revision} has no mask (the frame is rejected); send "
                "the mask the page shows as mask_png."
            )
        return load_mask(storage, label.mask_path)
    proposal = session.get(Proposal, proposal_id)
    if proposal is None or proposal.frame_id != frame.id:
        raise NotFoundError(f"Frame {frame.id} has no proposal {proposal_id}.")
    return load_mask(storage, proposal.mask_path)


# --- labels ------------------------------------------------------------------------------------


def current_label(session: Session, frame_id: int) -> Label | None:
    return session.scalar(sa.select(Label).where(Label.frame_id == frame_id))


def frame_mask(frame: Frame, mask_png: bytes) -> NDArray[np.bool_]:
    """A mask a person sent for ``frame``, decoded, or one sentence when its size is not the
    frame's (read from its header, before any pixel is decoded): the one rule for labels and
    annotators' own labels."""
    return decode_mask_png(mask_png, shape=(frame.height, frame.width))


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


def _check_role(status: LabelStatus, user: User) -> None:
    if status in (LabelStatus.accepted, LabelStatus.rejected) and not may(user, Action.review):
        raise PermissionDeniedError(
            f"Only reviewers may mark a label {status.value}; save it as corrected instead."
        )


def _label_content(
    frame: Frame,
    status: LabelStatus,
    mask_png: bytes | None,
    keypoints: list[list[float]] | None,
    proposal: Proposal | None,
) -> tuple[NDArray[np.bool_] | None, str | None, list[list[float]] | None]:
    """What the label holds: a new mask (decoded and checked) or the proposal's stored one,
    and its keypoints (given, else Algorithm 1's on a new mask, else the proposal's); nothing
    for a rejection."""
    if status == LabelStatus.rejected:
        return None, None, None
    if mask_png is not None:
        mask = frame_mask(frame, mask_png)
        if not mask.any():
            raise InvalidInputError(
                "The mask is empty (pool pixels are 255, or 1 in a mask of 0 and 1; values "
                "under 128 are outside); reject the frame if it shows no pool."
            )
        return mask, None, check_keypoints(frame, keypoints) if keypoints else mask_keypoints(mask)
    if proposal is not None:
        chosen = check_keypoints(frame, keypoints) if keypoints else proposal.keypoints
        return None, proposal.mask_path, chosen
    raise InvalidInputError(
        "The frame has no proposal to accept; send a mask_png or run the teacher first."
    )


def mask_fields(
    storage: Storage,
    mask: NDArray[np.bool_] | None,
    mask_path: str | None,
    proposal: Proposal | None,
) -> tuple[dict[str, Any], StoredFile | None]:
    """The label's mask columns (path, ``outline.mask_record``, whether it differs from the
    proposal's), storing a new mask's file (returned, to discard on failure)."""
    stored: StoredFile | None = None
    columns: dict[str, Any] = dict.fromkeys(("mask_rle", "mask_area", "mask_bbox", "mask_outlines"))
    changed: bool | None = None
    if mask is not None:
        changed = proposal is None or not np.array_equal(
            mask, load_mask(storage, proposal.mask_path)
        )
        columns = mask_record(mask)
        stored = store_mask_file(storage, mask)
        mask_path = stored.path
    elif mask_path is not None:
        changed = False
        columns = mask_record(load_mask(storage, mask_path))
    return {"mask_path": mask_path, **columns, "mask_changed": changed}, stored


def write_label(
    session: Session,
    frame: Frame,
    label: Label | None,
    base_revision: int,
    values: dict[str, Any],
    *,
    flush: bool = True,
) -> Label:
    """The label row (new, or updated only at ``base_revision``) and its history row. A new
    row is flushed at once (a concurrent first label fails here) unless ``flush`` is False (a
    batch flushes all of its rows at its commit). The label's facets (what the frames list
    filters on) are written with it."""
    new = label is None
    if label is None:
        label = Label(frame_id=frame.id, revision=1, **values)
        session.add(label)
        if flush:
            session.flush()
    else:
        updated = updated_one(
            session,
            sa.update(Label)
            .where(Label.frame_id == frame.id, Label.revision == base_revision)
            .values(revision=base_revision + 1, **values),
        )
        if not updated:
            raise stale_revision(session, frame.id)
    session.add(
        LabelRevision(
            frame_id=frame.id,
            revision=base_revision + 1,
            status=values["status"],
            mask_path=values["mask_path"],
            keypoints=values["keypoints"],
            proposal_id=values["proposal_id"],
            mask_changed=values["mask_changed"],
            source=values.get("source"),
            review=values.get("review"),
            review_comment=values.get("review_comment"),
            objects=values.get("objects"),
            frame_tags=values.get("frame_tags"),
            user_id=values["updated_by_id"],
        )
    )
    labelfacets.index_label(session, frame.id, values, new=new)
    frame.status = FrameStatus(values["status"].value)
    return label


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
    review_stage: bool = False,
    others: OtherClasses | None = None,
) -> Label:
    """Accept, correct or reject a frame's proposal, guarded by the label's revision.

    With the review stage on, an annotator's label awaits a reviewer (``review_label``) and a
    reviewer's own is approved as it is saved; off, ``review`` stays NULL (counts as approved).

    ``base_revision`` is the revision the client saw (0 when there was no label); a stale one
    raises ConflictError with the current revision. Every change is kept in the history.
    Keypoints of a corrected mask are recomputed by Algorithm 1 unless given. The label records
    the proposal it started from (``proposal_id``, default the one the policy shows) and whether
    its mask differs from that proposal's. ``others``: the other classes' objects and the
    frame's tags and attributes (what is not given stays as the label holds it).
    """
    frame_id = frame.id
    lock_frame(session, frame_id)  # a deletion now waits for this save (PostgreSQL)
    _check_role(status, user)
    proposal = pick(session, storage, frame.id, proposal_id=proposal_id)
    mask, mask_path, keypoints = _label_content(frame, status, mask_png, keypoints, proposal)
    label = current_label(session, frame.id)
    check_base(session, frame.id, label, base_revision)  # refused before anything is written
    extra = (others or OtherClasses()).columns(session, frame, label)
    fields, stored = mask_fields(storage, mask, mask_path, proposal)
    values = (
        fields
        | extra
        | {
            "status": status,
            "keypoints": keypoints,
            "proposal_id": proposal.id if proposal else None,
            "source": None,  # drawn here, whatever an earlier revision was imported from
            "updated_by_id": user.id,
            "updated_at": utcnow(),
            "review": saved_review(user, review_stage),
            "review_comment": None,
        }
    )
    try:
        label = write_label(session, frame, label, base_revision, values)
        session.commit()
    except BaseException as exc:
        session.rollback()
        if stored is not None:
            storage.discard([stored], in_use=masks_in_use(session, [stored.path]))
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


@dataclass(frozen=True)
class OtherClasses:
    """What a save says of the classes beside the pool (None: unchanged), and which of the
    label's retired parts (``labelconfig.retired``) it removes."""

    objects: list[dict[str, Any]] | None = None
    tags: list[str] | None = None
    attributes: dict[str, Any] | None = None
    remove_retired: Retired | None = None

    def columns(
        self, session: Session, frame: Frame, label: Label | OverlapLabel | None
    ) -> dict[str, Any]:
        """The label's ``objects`` and ``frame_tags`` (the frame's label, or an annotator's
        own): the given ones checked against the label configuration, the others as ``label``
        holds them; what the configuration retired stays unless removed (the one rule,
        ``retired.Save``)."""
        objects = label.objects if label is not None else None
        held = label.frame_tags if label is not None else None
        given = (self.objects, self.tags, self.attributes, self.remove_retired)
        if all(part is None for part in given):
            return {"objects": objects, "frame_tags": held or None}
        save = retired.Save(
            self.objects, self.tags, self.attributes, self.remove_retired or Retired()
        )
        return save.columns(labelconfig.current(session), objects, held, frame.height, frame.width)


def saved_review(user: User, review_stage: bool) -> ReviewState | None:
    """The review state of a label ``user`` saves: the stage's one rule."""
    if not review_stage:
        return None
    return ReviewState.approved if may(user, Action.review) else ReviewState.awaiting


def review_label(
    session: Session,
    frame: Frame,
    user: User,
    *,
    approve: bool,
    base_revision: int,
    comment: str | None,
    review_stage: bool,
) -> Label:
    """A reviewer approves an annotator's label, or sends it back with a comment: a new
    revision with the same content, by the reviewer (the history shows who decided). Sent
    back, the frame is handed to the annotator who saved the label (``app.users.work``)."""
    if not review_stage:
        raise InvalidInputError(
            "The review stage is off (WELDPOOL_REVIEW_STAGE): saved labels count at once."
        )
    if not may(user, Action.review):
        raise PermissionDeniedError("Only reviewers approve labels or send them back.")
    lock_frame(session, frame.id)
    label = current_label(session, frame.id)
    if label is None:
        raise NotFoundError(f"Frame {frame.id} has no label to review.")
    check_base(session, frame.id, label, base_revision)
    wanted = ReviewState.approved if approve else ReviewState.returned
    if label.review in (None, ReviewState.approved) and approve:
        raise ConflictError("This label is approved already.")
    if label.review == ReviewState.returned and not approve:
        raise ConflictError("This label was sent back already; it waits for its annotator.")
    text = (comment or "").strip()
    if not approve and not text:
        raise InvalidInputError("Say what to change: sending a label back needs a comment.")
    values = {
        "status": label.status,
        "mask_path": label.mask_path,
        "keypoints": label.keypoints,
        "proposal_id": label.proposal_id,
        "mask_changed": label.mask_changed,
        "source": label.source,
        "updated_by_id": user.id,
        "updated_at": utcnow(),
        "review": wanted,
        "review_comment": text or None,
        "objects": label.objects,
        "frame_tags": label.frame_tags,
    }
    submitter = label.updated_by_id
    try:
        label = write_label(session, frame, label, base_revision, values)
        if not approve and submitter is not None:
            frame.assignee_id, frame.assigned_at = submitter, utcnow()
        session.commit()
    except sa.exc.IntegrityError:
        session.rollback()
        raise stale_revision(session, frame.id) from None
    session.refresh(label)
    return label


class MovedOn(ConflictError):
    """A click refines a label revision that is no longer the label's (or never was)."""

    def __init__(self, current: int, named: int) -> None:
        super().__init__(
            f"The label is at revision {current}, not {named}; reload the frame and refine the "
            "mask it shows."
        )
        self.extra = {"revision": current}


class StaleRevision(ConflictError):
    """A label (or a frame's validation keypoints, ``what``) changed since the client read it:
    who changed it, and its revision now."""

    def __init__(self, current: int, by: str | None = None, what: str = "label") -> None:
        who = f"by {by}" if by else "by someone else"
        were, it = ("were", "them") if what.endswith("s") else ("was", "it")
        super().__init__(
            f"The {what} {were} changed {who} (now at revision {current}); reload {it} and "
            f"apply your change again, or overwrite with base_revision {current}."
        )
        self.current = current
        self.extra = {"revision": current, "updated_by": by}


def check_base(
    session: Session,
    frame_id: int,
    row: Label | ValidationKeypoints | None,
    base_revision: int,
    keypoints: bool = False,
) -> None:
    """The one base-revision rule: a save names the revision it started from (0 when there was
    none); any other is stale, a 409 naming the current revision and its author."""
    if base_revision != (row.revision if row is not None else 0):
        raise stale_revision(session, frame_id, keypoints)


def stale_revision(session: Session, frame_id: int, keypoints: bool = False) -> StaleRevision:
    """The conflict for a stale save of a frame's label (or of its validation ``keypoints``),
    naming the current revision and its author."""
    table, author = (
        (ValidationKeypoints, ValidationKeypoints.user_id)
        if keypoints
        else (Label, Label.updated_by_id)
    )
    row = session.execute(
        sa.select(table.revision, User.username)
        .outerjoin(User, User.id == author)
        .where(table.frame_id == frame_id)
    ).first()
    what = "validation keypoints" if keypoints else "label"
    return StaleRevision(row[0], row[1], what) if row else StaleRevision(0, what=what)


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
    session: Session,
    frame: Frame,
    user: User,
    keypoints: list[list[float]],
    base_revision: int | None = None,
) -> ValidationKeypoints:
    """Manual keypoints; the frame moves to the validation split and never trains the student.
    ``base_revision``: the revision the edit started from (0: none yet); a 409 when the stored
    keypoints have moved on (``None``: they are replaced whatever they are)."""
    if not keypoints:
        raise InvalidInputError("Give at least one keypoint.")
    points = check_keypoints(frame, keypoints)
    frame_id = frame.id
    for attempt in (1, 2):
        lock_frame(session, frame_id)
        row = set_validation_keypoints(session, frame, user, points, base_revision)
        try:
            session.commit()
            return row
        except sa.exc.IntegrityError:  # two first ones at once (SQLite, which locks no row)
            session.rollback()
            if not frame_exists(session, frame_id):
                raise FrameDeleted(frame_id) from None
            if base_revision is not None or attempt == 2:
                raise stale_revision(session, frame_id, keypoints=True) from None
            # Without a base the other's first ones are replaced: once more, as an update.
    raise AssertionError("unreachable")


def set_validation_keypoints(
    session: Session,
    frame: Frame,
    user: User,
    points: list[list[float]],
    base_revision: int | None = None,
) -> ValidationKeypoints:
    """The frame's validation keypoints row, written (not committed), and its split moved to
    validation. ``points`` are checked already (``check_keypoints``); ``base_revision`` as in
    ``save_validation_keypoints``."""
    row = session.scalar(
        sa.select(ValidationKeypoints).where(ValidationKeypoints.frame_id == frame.id)
    )
    if base_revision is not None:  # None: overwrite whatever is there
        check_base(session, frame.id, row, base_revision, keypoints=True)
    if row is None:
        row = ValidationKeypoints(frame_id=frame.id, keypoints=points, user_id=user.id, revision=1)
        session.add(row)
    else:  # where the revision is still the one read (a writer in between: stale)
        moved = updated_one(
            session,
            sa.update(ValidationKeypoints)
            .where(ValidationKeypoints.id == row.id, ValidationKeypoints.revision == row.revision)
            .values(
                keypoints=points,
                user_id=user.id,
                updated_at=utcnow(),
                revision=ValidationKeypoints.revision + 1,
            )
            .execution_options(synchronize_session=False),
        )
        if not moved:
            raise stale_revision(session, frame.id, keypoints=True)
        session.refresh(row)  # as written
    frame.split = Split.validation
    return row


def get_validation_keypoints(session: Session, frame_id: int) -> ValidationKeypoints:
    row = session.scalar(
        sa.select(ValidationKeypoints).where(ValidationKeypoints.frame_id == frame_id)
    )
    if row is None:
        raise NotFoundError(f"Frame {frame_id} has no validation keypoints.")
    return row
