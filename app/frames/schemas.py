"""Sequence, frame and video payloads of the REST API."""

from __future__ import annotations

import datetime as dt
import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from app.core.bounds import MAX_MM_PER_PX, MIN_MM_PER_PX, XY, Id, InputModel
from app.core.errors import InvalidInputError
from app.core.models import FrameStatus, LabelStatus, ReviewState, Split
from weldpool_core.geometry import scale_from_points


def scale_problem(mm_per_px: float) -> str | None:
    """Why ``mm_per_px`` cannot be a run's scale (outside the physical range), or None."""
    if math.isfinite(mm_per_px) and MIN_MM_PER_PX <= mm_per_px <= MAX_MM_PER_PX:
        return None
    bound = (
        f"more than {MAX_MM_PER_PX:g}" if mm_per_px > MAX_MM_PER_PX else f"under {MIN_MM_PER_PX:g}"
    )
    return (
        f"That is {mm_per_px:.3g} mm per pixel, {bound} mm per pixel; check the distance "
        "(millimetres) and the two points."
    )


def stored_scale(mm_per_px: float | None) -> float | None:
    """A stored scale as the API reads it: None when it is outside the physical range (a row
    written before the checks, or by hand), so that a stored value never breaks a read."""
    if mm_per_px is None or scale_problem(mm_per_px) is not None:
        return None
    return mm_per_px


class SequenceIn(InputModel):
    """A weld run and its process parameters (the paper's Table I)."""

    name: str = Field(min_length=1, max_length=200)
    wire_feed_m_min: float | None = Field(default=None, ge=0, description="Wire feed rate, m/min.")
    voltage_v: float | None = Field(default=None, ge=0, description="Voltage, V.")
    current_a: float | None = Field(default=None, ge=0, description="Current, A.")
    arc_length_correction_pct: float | None = Field(
        default=None, description="Arc length correction, %."
    )
    robot_speed_cm_min: float | None = Field(default=None, ge=0, description="Robot speed, cm/min.")
    synergic_law: str | None = Field(
        default=None, max_length=200, description="Synergic law used instead of fixed V / A."
    )
    joint_type: str | None = Field(default=None, max_length=64, description="e.g. fillet (Tee).")
    mm_per_px: float | None = Field(
        default=None,
        ge=MIN_MM_PER_PX,
        le=MAX_MM_PER_PX,
        description="Image scale at the pool, mm per pixel.",
    )
    notes: str = Field(default="", max_length=10_000)


class ScalePoints(InputModel):
    """Two points on a frame of the run (pixels) a known distance apart, e.g. the ends of a
    scale bar or of a gauge in view: the run's scale is the distance over their separation."""

    points: list[XY] = Field(min_length=2, max_length=2)
    distance_mm: float = Field(gt=0, le=10_000, description="The real distance, mm.")

    @property
    def mm_per_px(self) -> float:
        """The scale the points give (``weldpool_core.geometry.scale_from_points``)."""
        first, second = self.points
        return scale_from_points((first[0], first[1]), (second[0], second[1]), self.distance_mm)

    @model_validator(mode="after")
    def _scale_is_physical(self) -> ScalePoints:
        try:
            problem = scale_problem(self.mm_per_px)
        except InvalidInputError as exc:  # points on one spot
            problem = exc.message
        if problem:
            raise PydanticCustomError("scale_points", problem)
        return self


class SequencePatch(InputModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    wire_feed_m_min: float | None = Field(default=None, ge=0)
    voltage_v: float | None = Field(default=None, ge=0)
    current_a: float | None = Field(default=None, ge=0)
    arc_length_correction_pct: float | None = None
    robot_speed_cm_min: float | None = Field(default=None, ge=0)
    synergic_law: str | None = Field(default=None, max_length=200)
    joint_type: str | None = Field(default=None, max_length=64)
    mm_per_px: float | None = Field(default=None, ge=MIN_MM_PER_PX, le=MAX_MM_PER_PX)
    scale_points: ScalePoints | None = Field(
        default=None, description="Set mm_per_px from two points a known distance apart."
    )
    notes: str | None = Field(default=None, max_length=10_000)

    @model_validator(mode="after")
    def _name_and_notes_are_never_null(self) -> SequencePatch:
        for field in ("name", "notes"):
            if field in self.model_fields_set and getattr(self, field) is None:
                raise ValueError(f"{field} cannot be null; leave it out to keep it")
        if {"mm_per_px", "scale_points"} <= self.model_fields_set:
            raise ValueError("give mm_per_px or scale_points, not both")
        return self


class SequenceOut(BaseModel):
    """A weld run as stored. Unlike the inputs it bounds nothing: a value stored before a check
    existed (or written by hand) is read as it is, and a scale outside the physical range as
    null, so that a stored row never breaks a read."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    wire_feed_m_min: float | None = Field(default=None, description="Wire feed rate, m/min.")
    voltage_v: float | None = Field(default=None, description="Voltage, V.")
    current_a: float | None = Field(default=None, description="Current, A.")
    arc_length_correction_pct: float | None = Field(
        default=None, description="Arc length correction, %."
    )
    robot_speed_cm_min: float | None = Field(default=None, description="Robot speed, cm/min.")
    synergic_law: str | None = Field(
        default=None, description="Synergic law used instead of fixed V / A."
    )
    joint_type: str | None = Field(default=None, description="e.g. fillet (Tee).")
    mm_per_px: float | None = Field(
        default=None,
        description="Image scale at the pool, mm per pixel; null when unknown or outside "
        f"{MIN_MM_PER_PX:g}–{MAX_MM_PER_PX:g}.",
    )
    notes: str = ""
    created_at: dt.datetime
    frame_count: int = 0

    @field_validator("mm_per_px", mode="before")
    @classmethod
    def _scale_in_range(cls, value: Any) -> Any:
        return stored_scale(value) if isinstance(value, int | float) else value


class FrameOut(BaseModel):
    """A stored frame."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    sequence_id: int | None
    sha256: str
    original_name: str
    media_type: str
    size_bytes: int
    width: int
    height: int
    channels: int
    bit_depth: int
    video_id: int | None
    frame_index: int | None
    timestamp_s: float | None
    split: Split
    status: FrameStatus
    uncertainty: float | None
    teacher_error: str | None = Field(
        default=None, description="Why the teacher's last run failed on this frame, if it did."
    )
    uncertainty_reason: str | None = Field(
        default=None, description="The component that puts the frame high in the queue."
    )
    created_at: dt.datetime
    assignee_id: int | None = Field(
        default=None, description="The user the frame is handed to (`POST /frames/assign`)."
    )
    assignee: str | None = Field(default=None, description="That user's name.")
    review: ReviewState | None = Field(
        default=None,
        description="In lists: where the label stands in the review stage (`awaiting`, "
        "`returned`: sent back, `approved`); null without one.",
    )
    review_comment: str | None = Field(
        default=None, description="In lists: why a reviewer sent the label back."
    )

    @field_validator("assignee", mode="before")
    @classmethod
    def _assignee_name(cls, value: Any) -> Any:
        return getattr(value, "username", value)


class LabelState(BaseModel):
    status: LabelStatus
    revision: int
    updated_at: dt.datetime
    review: ReviewState | None = Field(
        default=None, description="The review stage's state of the label (null: stage off)."
    )


class ProposalState(BaseModel):
    id: int
    source: str
    model_id: str
    created_at: dt.datetime


class FrameDetail(FrameOut):
    """A frame with where it stands in the review loop."""

    uncertainty_components: dict[str, float | None] | None = None
    label: LabelState | None = None
    proposal: ProposalState | None = None
    has_validation_keypoints: bool = False


class FramePage(BaseModel):
    items: list[FrameOut]
    total: int
    limit: int
    offset: int
    next_after: str | None = Field(
        default=None,
        description="Cursor of the next page (pass it as `after`); null on the last page.",
    )
    ordering: str | None = Field(
        default=None, description="How the list is ordered, where the scores do not show it."
    )


class Rejected(BaseModel):
    name: str
    reason: str


class Duplicate(BaseModel):
    name: str
    sha256: str
    frame_id: int = Field(description="The frame that already holds this content.")


class AlsoIn(BaseModel):
    """A stored frame whose content another run (or no run) holds too."""

    frame_id: int = Field(description="The frame just stored.")
    other_frame_id: int
    sequence_id: int | None
    sequence_name: str | None = Field(description="That run's name; null: a frame of no run.")


class IngestOut(BaseModel):
    """What became of each uploaded file."""

    stored: list[FrameOut]
    duplicates: list[Duplicate]
    rejected: list[Rejected]
    also_in: list[AlsoIn] = Field(
        default_factory=list,
        description="Frames stored here whose content is in another run too (a run holds a "
        "content once; the same image in two runs is two frames): the first other frame of each.",
    )


class VideoOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    sequence_id: int
    sha256: str
    original_name: str
    container: str
    size_bytes: int
    width: int
    height: int
    fps: float
    frame_count: int
    every_nth: int
    job_id: int | None
    created_at: dt.datetime


class VideoAccepted(BaseModel):
    job_id: int
    video: VideoOut


class DeletionOut(BaseModel):
    deleted_frames: int
    deleted_reviewed: int = Field(description="Of them, frames with reviewed labels.")
    removed_files: int = Field(description="Stored files no other row named.")


class AssignIn(InputModel):
    """Frames to hand to a person: a selection, or the next frames of the review queue."""

    frame_ids: list[Id] | None = Field(default=None, min_length=1, max_length=10_000)
    next: int | None = Field(
        default=None,
        ge=1,
        le=1000,
        description="Instead of frame_ids: the next N frames of the queue (still to review, "
        "most uncertain first) that nobody has yet.",
    )
    sequence_id: Id | None = Field(default=None, description="With next: that run's queue.")
    assignee_id: Id | None = Field(description="The user; null takes the frames back.")


class AssignOut(BaseModel):
    assigned: int
    frame_ids: list[int]
    assignee: str | None


class FramesDeleteIn(InputModel):
    frame_ids: list[Id] = Field(min_length=1, max_length=10_000)
    force: bool = Field(default=False, description="Also delete frames with reviewed labels.")
