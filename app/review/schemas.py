"""Payloads of the review loop: teacher runs, proposals, clicks, labels, manual keypoints."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, Field, model_validator

from app.core.bounds import MAX_ID, XY, Id, InputModel
from app.core.models import LabelStatus, ReviewState, Split
from weldpool_core.outline import MAX_POLYGONS, MAX_VERTICES

MAX_KEYPOINTS = 64
"""Most keypoints a label or a validation set of one frame may hold."""


class Point(InputModel):
    x: float
    y: float
    positive: bool = True


class MaskFrom(InputModel):
    """A stored mask of the frame: its label at ``label_revision``, or proposal ``proposal_id``."""

    label_revision: int | None = Field(default=None, ge=1, le=MAX_ID)
    proposal_id: Id | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> MaskFrom:
        if (self.label_revision is None) == (self.proposal_id is None):
            raise ValueError("mask_from names either label_revision or proposal_id")
        return self


class SegmentIn(InputModel):
    """Clicks and/or a box in frame pixels, optionally refining a previous mask."""

    points: list[Point] = Field(default_factory=list, max_length=64)
    box: tuple[float, float, float, float] | None = Field(
        default=None, description="[x0, y0, x1, y1], inside the frame (its edges included)."
    )
    mask_png: str | None = Field(
        default=None, description="A previous mask to refine (base64 PNG)."
    )
    mask_from: MaskFrom | None = Field(
        default=None,
        description="Instead of mask_png, a mask the server has: the frame's label at a "
        "revision, or one of its proposals (the review page's first click sends no PNG).",
    )

    @model_validator(mode="after")
    def _one_previous_mask(self) -> SegmentIn:
        if self.mask_png is not None and self.mask_from is not None:
            raise ValueError("give mask_png or mask_from, not both")
        return self


class SegmentOut(BaseModel):
    mask_png: str
    score: float = Field(description="SAM2's predicted IoU of the returned mask.")
    scores: list[float]
    elapsed_ms: float = Field(description="Server time for this click.")
    embedding: Literal["memory", "disk", "shared", "computed"]


class PropagateIn(InputModel):
    """Carry reviewed masks through the run with SAM2's video model."""

    from_frame_ids: list[Id] = Field(
        min_length=1, max_length=64, description="Reviewed frames of the run to start from."
    )
    direction: Literal["forward", "backward", "both"] = "both"
    until_frame_index: int | None = Field(
        default=None, ge=0, le=MAX_ID, description="Stop at this frame index (one direction)."
    )
    threshold: float = Field(
        default=0.5,
        ge=0,
        le=1,
        description="Frames under this confidence are flagged; three in a row stop a pass.",
    )


class ExportIn(InputModel):
    """Which labels to export and how; run as a job for big sets."""

    format: Literal["coco", "masks", "yolo", "cvat", "labelme"] = "coco"
    sequence_id: Id | None = None
    split: Split | None = None


class OutlineIn(InputModel):
    """A mask to trace as polygons (the outline the reviewer edits vertex by vertex)."""

    mask_png: str = Field(description="The mask (base64 PNG, the frame's size).")
    tolerance: float = Field(
        default=1.0, ge=0, le=20, description="Simplification in pixels (0: every pixel)."
    )


class PolygonIO(InputModel):
    """One closed boundary in frame pixels; ``hole`` when it bounds a hole in its region."""

    points: list[XY] = Field(min_length=3, max_length=MAX_VERTICES)
    hole: bool = False


class OutlineOut(BaseModel):
    polygons: list[PolygonIO] = Field(description="Outer boundaries, each followed by its holes.")


class OutlineMaskIn(InputModel):
    """An edited outline to turn back into a mask: at most ``MAX_VERTICES`` vertices in all,
    none more than one frame width or height outside the frame."""

    polygons: list[PolygonIO] = Field(max_length=MAX_POLYGONS)

    @model_validator(mode="before")
    @classmethod
    def _vertices_in_all(cls, data: Any) -> Any:
        # Counted before each vertex is validated, so the refusal costs no more than the count.
        polygons = data.get("polygons") if isinstance(data, dict) else None
        if isinstance(polygons, list):
            total = sum(
                len(p["points"])
                for p in polygons
                if isinstance(p, dict) and isinstance(p.get("points"), list)
            )
            if total > MAX_VERTICES:
                raise ValueError(f"an outline has at most {MAX_VERTICES:,} vertices in all")
        return data


class OutlineMaskOut(BaseModel):
    mask_png: str = Field(description="Single-channel PNG (0 / 255), base64.")
    area: int = Field(description="Pixels inside the outline.")


class RetiredParts(InputModel):
    """Parts of a label that the label configuration no longer accepts (a class, tag or
    attribute removed with ``force``): positions in the label's ``objects``, tag names,
    attribute names. They stay stored until a save names them in ``remove_retired``."""

    objects: list[int] = Field(default_factory=list, max_length=1000)
    tags: list[str] = Field(default_factory=list, max_length=64)
    attributes: list[str] = Field(default_factory=list, max_length=64)

    @model_validator(mode="after")
    def _positions(self) -> RetiredParts:
        if any(not 0 <= p < 1000 for p in self.objects):
            raise ValueError("an object's position is from 0 to 999")
        return self


class LabelIn(InputModel):
    """A reviewer's verdict; ``base_revision`` is the revision you saw (0: no label yet)."""

    status: LabelStatus
    base_revision: int = Field(ge=0, le=MAX_ID)
    mask_png: str | None = Field(default=None, description="A corrected mask (base64 PNG).")
    keypoints: list[XY] | None = Field(default=None, max_length=MAX_KEYPOINTS)
    proposal_id: Id | None = Field(
        default=None,
        description="The proposal the label started from (default: the one the policy shows).",
    )
    objects: list[dict[str, Any]] | None = Field(
        default=None,
        max_length=1000,
        description="The other configured classes' objects (`/label-config`), each "
        '`{"class", …}`: a mask or instances class\'s region as `rle`, `mask_png` or '
        "`polygons`, a points class's `points` `{name: [x, y]}`, and `attributes`. "
        "Omitted: the label's objects stay as they are; `[]` removes them.",
    )
    tags: list[str] | None = Field(
        default=None, max_length=64, description="The frame's tags (omitted: as they are)."
    )
    attributes: dict[str, Any] | None = Field(
        default=None, description="The frame's attributes (omitted: as they are)."
    )
    remove_retired: RetiredParts | None = Field(
        default=None,
        description="Retired parts of the label (its `retired`, as read at base_revision) "
        "to remove; any other retired part stays, whatever `objects`, `tags` and "
        "`attributes` say.",
    )

    @model_validator(mode="after")
    def _corrected_needs_a_change(self) -> LabelIn:
        if self.status == LabelStatus.corrected and self.mask_png is None and not self.keypoints:
            raise ValueError("a corrected label needs a mask_png or keypoints")
        return self


class LabelOut(BaseModel):
    frame_id: int
    revision: int
    status: LabelStatus
    proposal_id: int | None = None
    mask_changed: bool | None = None
    mask_png: str | None
    keypoints: list[list[float]] | None
    source: dict[str, Any] | None = None
    """Where a label made elsewhere came from: ``{"kind": "imported", "format", "file"}``."""
    updated_by: str | None
    updated_at: dt.datetime
    review: ReviewState | None = Field(
        default=None,
        description="The review stage's state (`awaiting`, `approved`, `returned`); null: "
        "the stage was off when it was saved (counts as approved).",
    )
    review_comment: str | None = Field(
        default=None, description="Why a reviewer sent it back (or a note on approval)."
    )
    objects: list[dict[str, Any]] = Field(
        default_factory=list,
        description="The other classes' objects beside the pool's mask and keypoints.",
    )
    tags: list[str] = Field(default_factory=list, description="The frame's tags.")
    attributes: dict[str, Any] = Field(default_factory=dict, description="The frame's attributes.")
    retired: RetiredParts = Field(
        default_factory=RetiredParts,
        description="What of `objects`, `tags` and `attributes` the label configuration no "
        "longer accepts: kept and shown read-only until a save removes it (`remove_retired`).",
    )


class ReviewIn(InputModel):
    """A reviewer's decision on an annotator's label (the review stage)."""

    decision: Literal["approve", "return"]
    base_revision: int = Field(ge=1, le=MAX_ID)
    comment: str | None = Field(
        default=None, max_length=1000, description="What to change (needed to send it back)."
    )


class LabelRevisionOut(BaseModel):
    revision: int
    status: LabelStatus
    keypoints: list[list[float]] | None
    has_mask: bool
    source: dict[str, Any] | None = None
    review: ReviewState | None = None
    review_comment: str | None = None
    objects: list[dict[str, Any]] = Field(
        default_factory=list, description="The other classes' objects at this revision."
    )
    tags: list[str] = Field(default_factory=list, description="The frame's tags then.")
    user: str | None
    created_at: dt.datetime


class KeypointsIn(InputModel):
    keypoints: list[XY] = Field(min_length=1, max_length=MAX_KEYPOINTS)
    base_revision: int | None = Field(
        default=None,
        ge=0,
        le=MAX_ID,
        description="The revision of the keypoints this edit started from (0: none yet); 409, "
        "with the current `revision`, when they have changed since. Omitted: replace them.",
    )


class KeypointsOut(BaseModel):
    frame_id: int
    keypoints: list[list[float]]
    updated_at: dt.datetime
    revision: int
