"""Agreement: one frame labelled by several annotators, each label kept apart
(``OverlapLabel``), until a reviewer approves one of them or merges them into the frame's label.

- A reviewer gives frames to two or more annotators (``give_to_several``); each saves her own
  label of it (``save_own``), which never trains and which the others do not see.
- The frame's **agreement** is the mean over every pair of labelled annotators of the mask IoU,
  and of the keypoint distance (px: the mean distance from each keypoint of one to the nearest
  of the other, both ways); each other class of the label configuration has its own figures
  (``app.review.agreement_classes``), and the tags and attributes that differ are named;
  ``run_agreement`` averages them per weld run over the frames with two labels or more — the
  figures a lab quotes for its dataset.
- ``settle`` makes the frame's label (approved, by the reviewer) from the label of the
  annotator he chose, or from all of them merged: a pixel is pool where at least half of the
  labelled masks say so, and its keypoints are Algorithm 1's on that mask. A chosen label brings
  its objects, tags and attributes with it; a merged one leaves the frame label's as they are.
  Training takes the frame's label only, as ever.
"""

from __future__ import annotations

import itertools
import statistics
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import utcnow
from app.core.errors import InvalidInputError, NotFoundError, PermissionDeniedError
from app.core.housekeeping import doom
from app.core.models import Frame, Label, LabelStatus, OverlapLabel, Sequence, User
from app.core.permissions import Action, may
from app.labelconfig import service as labelconfig
from app.labelconfig.retired import retired
from app.proposals.files import store_mask
from app.proposals.policy import stored_iou
from app.review.agreement_classes import Figures, frame_class_agreement, mean_figures, nearest_px
from app.review.service import (
    OtherClasses,
    check_keypoints,
    current_label,
    frame_mask,
    save_label,
)
from app.storage import Storage
from app.storage.pixels import load_mask
from weldpool_core.heatmap import mask_keypoints
from weldpool_core.io import encode_mask_png

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

MAX_ANNOTATORS = 10
"""Most annotators one frame is given to."""


def give_to_several(session: Session, frame_ids: list[int], user_ids: list[int]) -> int:
    """Give each frame to each of the annotators (two or more, active); returns how many
    (frame, annotator) pairs are new. A pair given already keeps its label."""
    people = list(dict.fromkeys(user_ids))
    if not 2 <= len(people) <= MAX_ANNOTATORS:
        raise InvalidInputError(f"Give the frames to 2 to {MAX_ANNOTATORS} different people.")
    users = {u.id: u for u in session.scalars(sa.select(User).where(User.id.in_(people)))}
    for user_id in people:
        user = users.get(user_id)
        if user is None:
            raise NotFoundError(f"There is no user {user_id}.")
        if not user.is_active:
            raise InvalidInputError(f"{user.username} is deactivated; reactivate them first.")
    ids = list(dict.fromkeys(frame_ids))
    found = set(session.scalars(sa.select(Frame.id).where(Frame.id.in_(ids))))
    if missing := [i for i in ids if i not in found]:
        raise NotFoundError(f"There is no frame {missing[0]}.")
    given: set[tuple[int, int]] = set(
        session.execute(
            sa.select(OverlapLabel.frame_id, OverlapLabel.user_id).where(
                OverlapLabel.frame_id.in_(ids), OverlapLabel.user_id.in_(people)
            )
        ).all()
    )
    new = [(f, u) for f in ids for u in people if (f, u) not in given]
    session.add_all(OverlapLabel(frame_id=f, user_id=u) for f, u in new)
    session.commit()
    return len(new)


def own_row(session: Session, frame_id: int, user: User) -> OverlapLabel:
    """The caller's own label of a frame given to several (403 when it is not given to her)."""
    row = session.scalar(
        sa.select(OverlapLabel).where(
            OverlapLabel.frame_id == frame_id, OverlapLabel.user_id == user.id
        )
    )
    if row is None:
        raise PermissionDeniedError(
            f"Frame {frame_id} is not given to you for agreement; save its label instead."
        )
    return row


def save_own(
    session: Session,
    storage: Storage,
    frame: Frame,
    user: User,
    mask_png: bytes,
    keypoints: list[list[float]] | None,
    others: OtherClasses | None = None,
) -> OverlapLabel:
    """The annotator's own label of the frame (her mask; keypoints given, else Algorithm 1's;
    her objects of the other classes, tags and attributes, each kept as it was when not given);
    the mask it replaces is left to the collector (no revision keeps it)."""
    row = own_row(session, frame.id, user)
    mask = frame_mask(frame, mask_png)
    if not mask.any():
        raise InvalidInputError("The mask is empty: draw the pool before saving.")
    extra = (others or OtherClasses()).columns(session, frame, row)
    row.keypoints = check_keypoints(frame, keypoints) if keypoints else mask_keypoints(mask)
    row.objects, row.frame_tags = extra["objects"], extra["frame_tags"]
    replaced, row.mask_path = row.mask_path, store_mask(storage, mask)
    if replaced and replaced != row.mask_path:
        doom(session, {replaced})
    row.updated_at = utcnow()
    session.commit()
    return row


@dataclass(frozen=True)
class Agreement:
    """How far a frame's labels agree: mean pairwise mask IoU and keypoint distance (px), each
    other class's figures (``agreement_classes``) and the tags and attributes that differ."""

    labelled: int
    mask_iou: float | None
    keypoint_px: float | None
    classes: list[Figures]
    differ: dict[str, list[str]]


def class_kinds(session: Session) -> dict[str, str]:
    """Each configured class's kind, by name (what its agreement is measured by)."""
    return {name: spec["kind"] for name, spec in labelconfig.current(session).classes().items()}


def agreement_of(storage: Storage, rows: list[OverlapLabel], kinds: dict[str, str]) -> Agreement:
    """The agreement of one frame's labelled rows (module doc)."""
    done = [r for r in rows if r.mask_path]
    ious: list[float] = []
    distances: list[float] = []
    for a, b in itertools.combinations(done, 2):
        assert a.mask_path and b.mask_path
        ious.append(stored_iou(storage.existing(a.mask_path), storage.existing(b.mask_path)))
        if (distance := nearest_px(a.keypoints, b.keypoints)) is not None:
            distances.append(distance)
    classes, differ = frame_class_agreement([(r.objects, r.frame_tags) for r in done], kinds)
    return Agreement(
        len(done),
        statistics.fmean(ious) if ious else None,
        statistics.fmean(distances) if distances else None,
        classes,
        differ if len(done) >= 2 else {"tags": [], "attributes": []},
    )


def frame_rows(session: Session, frame_id: int) -> list[tuple[OverlapLabel, str]]:
    """The frame's rows with each annotator's name, by name."""
    return [
        (row, name)
        for row, name in session.execute(
            sa.select(OverlapLabel, User.username)
            .join(User, User.id == OverlapLabel.user_id)
            .where(OverlapLabel.frame_id == frame_id)
            .order_by(sa.func.lower(User.username))
        )
    ]


def merged_mask(storage: Storage, rows: list[OverlapLabel]) -> np.ndarray:
    """Pool where at least half of the labelled masks say so."""
    masks = [load_mask(storage, r.mask_path) for r in rows if r.mask_path]
    votes = np.sum(masks, axis=0)
    return np.asarray(votes * 2 >= len(masks))


def settle(
    session: Session,
    storage: Storage,
    frame: Frame,
    reviewer: User,
    *,
    choose: int | None,
    review_stage: bool,
) -> Label:
    """The frame's label from the annotator ``choose`` (a user id), or (None) from every
    labelled one merged: saved by the reviewer as corrected (approved with the review stage)."""
    if not may(reviewer, Action.review):
        raise PermissionDeniedError("Only reviewers approve or merge annotators' labels.")
    rows = [row for row, _ in frame_rows(session, frame.id) if row.mask_path]
    if choose is not None:
        picked = next((r for r in rows if r.user_id == choose), None)
        if picked is None:
            raise InvalidInputError(f"User {choose} has no label of frame {frame.id} to approve.")
        mask, keypoints = load_mask(storage, picked.mask_path or ""), picked.keypoints
        held = picked.frame_tags or {}
        # What the configuration retired since she saved is not resent: the frame's label
        # keeps its own retired parts, hers stay on her own label.
        gone = retired(labelconfig.current(session), picked.objects, held)
        others = OtherClasses(
            objects=[
                _resent(o) for i, o in enumerate(picked.objects or []) if i not in gone.objects
            ],
            tags=[t for t in held.get("tags", []) if t not in gone.tags],
            attributes={
                k: v for k, v in held.get("attributes", {}).items() if k not in gone.attributes
            },
        )
    else:
        if len(rows) < 2:
            raise InvalidInputError("Merging needs two labels or more; approve the one there is.")
        mask = merged_mask(storage, rows)
        if not mask.any():
            raise InvalidInputError("The labels share no pixel a majority agrees on.")
        keypoints, others = None, OtherClasses()
    label = current_label(session, frame.id)
    return save_label(
        session,
        storage,
        frame,
        reviewer,
        status=LabelStatus.corrected,
        base_revision=label.revision if label else 0,
        mask_png=encode_mask_png(mask),
        keypoints=keypoints,
        review_stage=review_stage,
        others=others,
    )


def _resent(item: dict[str, Any]) -> dict[str, Any]:
    """A stored object as a save gives it: its region once, as the polygons it was drawn as
    (kept with it, and its RLE made from them again) or else its RLE; area and box recomputed."""
    kept = ("class", "points", "attributes") if "points" in item else ("class", "attributes")
    resent = {k: item[k] for k in kept if k in item}
    region = "polygons" if item.get("polygons") is not None else "rle"
    if region in item:
        resent[region] = item[region]
    return resent


def run_agreement(session: Session, storage: Storage) -> list[dict[str, Any]]:
    """Per weld run (and frames in none): the frames labelled by two annotators or more, the
    mean of their agreement (mask IoU, keypoint distance in px), each other class's figures
    averaged over the frames that measure it, and how many frames' tags differ."""
    kinds = class_kinds(session)
    rows = session.execute(
        sa.select(OverlapLabel, Frame.sequence_id, Sequence.name)
        .join(Frame, Frame.id == OverlapLabel.frame_id)
        .outerjoin(Sequence, Sequence.id == Frame.sequence_id)
        .where(OverlapLabel.mask_path.is_not(None))
        .order_by(OverlapLabel.frame_id)
    )
    frames: dict[int, list[OverlapLabel]] = {}
    runs: dict[int, tuple[int | None, str | None]] = {}
    for row, sequence_id, name in rows:
        frames.setdefault(row.frame_id, []).append(row)
        runs[row.frame_id] = (sequence_id, name)
    per_run: dict[tuple[int | None, str | None], list[Agreement]] = {}
    for frame_id, labelled in frames.items():
        if len(labelled) >= 2:
            per_run.setdefault(runs[frame_id], []).append(agreement_of(storage, labelled, kinds))
    return [
        {
            "sequence_id": sequence_id,
            "sequence": name,
            "frames": len(values),
            "mask_iou": statistics.fmean(v.mask_iou for v in values if v.mask_iou is not None),
            "keypoint_px": _mean([v.keypoint_px for v in values]),
            "classes": _per_frame(values),
            "tags_differ": sum(1 for v in values if v.differ["tags"]),
        }
        for (sequence_id, name), values in sorted(per_run.items(), key=lambda i: str(i[0][1]))
    ]


def _per_frame(values: list[Agreement]) -> list[Figures]:
    """Each class's figures averaged over frames (``frames``: how many measure it)."""
    frames = [{c["class"]: c | {"pairs": 1} for c in v.classes} for v in values]
    return [
        {k: v for k, v in c.items() if k != "pairs"} | {"frames": c["pairs"]}
        for c in mean_figures(frames)
    ]


def _mean(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return statistics.fmean(present) if present else None
