"""/api/v1/frames/…/overlap: one frame labelled by several annotators, kept apart until a
reviewer approves one label or merges them (``app.review.agreement``)."""

from __future__ import annotations

import base64
from typing import Any

from fastapi import APIRouter
from pydantic import BaseModel, Field

from app.core.bounds import MAX_ID, XY, Id, IdPath, InputModel
from app.core.deps import QueueDep, SessionDep, SettingsDep, StorageDep
from app.core.errors import InvalidInputError
from app.core.models import get_frame
from app.core.permissions import Action, may
from app.core.security import CurrentUser, ReviewerUser
from app.labelconfig.service import MAX_OBJECTS
from app.review import agreement
from app.review.routes import _label_out, _png_bytes
from app.review.schemas import MAX_KEYPOINTS, LabelOut
from app.review.service import OtherClasses
from app.system.doctor import frame_file
from app.training.service import maybe_retrain

router = APIRouter(tags=["review"])


class OverlapIn(InputModel):
    frame_ids: list[Id] = Field(min_length=1, max_length=1000)
    user_ids: list[Id] = Field(
        min_length=2, max_length=agreement.MAX_ANNOTATORS, description="Two annotators or more."
    )


class OverlapGiven(BaseModel):
    given: int = Field(description="New (frame, annotator) pairs; pairs given already stay.")


class OwnLabelIn(InputModel):
    mask_png: str = Field(max_length=64 * 1024 * 1024, description="Her mask (base64 PNG).")
    keypoints: list[XY] | None = Field(default=None, max_length=MAX_KEYPOINTS)
    objects: list[dict[str, Any]] | None = Field(
        default=None,
        max_length=MAX_OBJECTS,
        description="Her objects of the other classes, as `PUT /frames/{id}/label` takes them "
        "(omitted: kept as they are; `[]` removes them).",
    )
    tags: list[str] | None = Field(
        default=None, max_length=64, description="Her frame tags (omitted: as they are)."
    )
    attributes: dict[str, Any] | None = Field(
        default=None, description="Her frame attributes (omitted: as they are)."
    )


class OverlapLabelOut(BaseModel):
    user_id: int
    username: str
    labelled: bool
    updated_at: str | None
    mask_png: str | None = Field(default=None, description="Her mask (base64 PNG).")
    keypoints: list[list[float]] | None = None
    objects: list[dict[str, Any]] = Field(default_factory=list, description="Her other objects.")
    tags: list[str] = Field(default_factory=list, description="Her frame tags.")
    attributes: dict[str, Any] = Field(default_factory=dict, description="Her frame attributes.")


class ClassAgreementOut(BaseModel):
    """One class's agreement, the mean over the pairs of annotators that drew it."""

    class_: str = Field(alias="class", serialization_alias="class")
    kind: str
    pairs: int = Field(description="Pairs of annotators either of whom drew the class.")
    iou: float | None = Field(description="Mask and instances: IoU of the class's union mask.")
    count_diff: float | None = Field(description="Instances: how many objects more one drew.")
    points_px: dict[str, float | None] = Field(
        description="Points: per named point, the distance between the annotators' (px)."
    )


class DifferOut(BaseModel):
    tags: list[str] = Field(description="Tags some labelled annotators gave and others did not.")
    attributes: list[str] = Field(description="Frame attributes they do not all give alike.")


class OverlapOut(BaseModel):
    labels: list[OverlapLabelOut] = Field(
        description="Every annotator's label (reviewers); an annotator gets her own only."
    )
    labelled: int
    mask_iou: float | None = Field(description="Mean mask IoU over every pair (reviewers).")
    keypoint_px: float | None = Field(description="Mean keypoint distance over every pair.")
    classes: list[ClassAgreementOut] = Field(
        default_factory=list, description="Each other class's agreement (reviewers)."
    )
    differ: DifferOut | None = Field(
        default=None, description="The frame tags and attributes that differ (reviewers)."
    )


class SettleIn(InputModel):
    choose: int | None = Field(
        default=None, ge=1, le=MAX_ID, description="The annotator whose label becomes the frame's."
    )
    merge: bool = Field(default=False, description="Merge every label (pixel majority).")


@router.post("/frames/overlap", response_model=OverlapGiven)
def give_to_several(body: OverlapIn, session: SessionDep, _reviewer: ReviewerUser) -> OverlapGiven:
    """Give frames to two annotators or more (reviewers): each labels it apart from the others,
    and their agreement is measured before a reviewer approves one label or merges them."""
    return OverlapGiven(given=agreement.give_to_several(session, body.frame_ids, body.user_ids))


@router.put("/frames/{frame_id}/overlap/mine", response_model=OverlapLabelOut)
def save_own(
    frame_id: IdPath, body: OwnLabelIn, session: SessionDep, storage: StorageDep, user: CurrentUser
) -> OverlapLabelOut:
    """Save one's own label of a frame given to several (it does not train, and the other
    annotators do not see it)."""
    frame = get_frame(session, frame_id)
    others = OtherClasses(objects=body.objects, tags=body.tags, attributes=body.attributes)
    mask_png = _png_bytes(body.mask_png, "mask_png")
    row = agreement.save_own(session, storage, frame, user, mask_png, body.keypoints, others)
    return _out(storage, row, user.username, with_mask=False)


def _out(storage: StorageDep, row, name: str, with_mask: bool) -> OverlapLabelOut:  # type: ignore[no-untyped-def]
    mask = None
    if with_mask and row.mask_path:
        data = frame_file(storage, row.mask_path, row.frame_id, "label mask").read_bytes()
        mask = base64.b64encode(data).decode("ascii")
    return OverlapLabelOut(
        user_id=row.user_id,
        username=name,
        labelled=row.mask_path is not None,
        updated_at=row.updated_at.isoformat() if row.updated_at else None,
        mask_png=mask,
        keypoints=row.keypoints,
        objects=row.objects or [],
        tags=(row.frame_tags or {}).get("tags", []),
        attributes=(row.frame_tags or {}).get("attributes", {}),
    )


@router.get("/frames/{frame_id}/overlap", response_model=OverlapOut)
def frame_overlap(
    frame_id: IdPath, session: SessionDep, storage: StorageDep, user: CurrentUser
) -> OverlapOut:
    """The frame's labels by several annotators and how far they agree (reviewers see every
    label; an annotator her own, and no figure until a reviewer decides)."""
    get_frame(session, frame_id)
    rows = agreement.frame_rows(session, frame_id)
    reviewer = may(user, Action.review)
    measured = agreement.agreement_of(storage, [r for r, _ in rows], agreement.class_kinds(session))
    shown = rows if reviewer else [(r, n) for r, n in rows if r.user_id == user.id]
    return OverlapOut(
        labels=[_out(storage, r, n, with_mask=True) for r, n in shown],
        labelled=measured.labelled,
        mask_iou=measured.mask_iou if reviewer else None,
        keypoint_px=measured.keypoint_px if reviewer else None,
        classes=[ClassAgreementOut.model_validate(c) for c in measured.classes] if reviewer else [],
        differ=DifferOut(**measured.differ) if reviewer else None,
    )


@router.post("/frames/{frame_id}/overlap/settle", response_model=LabelOut)
def settle(
    frame_id: IdPath,
    body: SettleIn,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    queue: QueueDep,
    reviewer: ReviewerUser,
) -> LabelOut:
    """The frame's label from one annotator's label (`choose`) or from all of them merged
    (`merge`: a pixel is pool where at least half say so): a new revision by the reviewer,
    approved; training takes it, never the annotators' own labels."""
    if (body.choose is None) == (not body.merge):
        raise InvalidInputError("Give either `choose` (a user id) or `merge`: true.")
    frame = get_frame(session, frame_id)
    label = agreement.settle(
        session,
        storage,
        frame,
        reviewer,
        choose=body.choose,
        review_stage=settings.review_stage,
    )
    maybe_retrain(session, queue, settings.retrain_every, reviewer)
    return _label_out(session, storage, label, reviewer)
