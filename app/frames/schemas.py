"""Sequence, frame and video payloads of the REST API."""

from __future__ import annotations

import datetime as dt

from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.bounds import MAX_MM_PER_PX, XY, Id, InputModel
from app.models import FrameStatus, LabelStatus, Split


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
        default=None, gt=0, le=MAX_MM_PER_PX, description="Image scale at the pool, mm per pixel."
    )
    notes: str = Field(default="", max_length=10_000)


class ScalePoints(InputModel):
    """Two points on a frame of the run (pixels) a known distance apart, e.g. the ends of a
    scale bar or of a gauge in view: the run's scale is the distance over their separation."""

    points: list[XY] = Field(min_length=2, max_length=2)
    distance_mm: float = Field(gt=0, le=10_000, description="The real distance, mm.")


class SequencePatch(InputModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    wire_feed_m_min: float | None = Field(default=None, ge=0)
    voltage_v: float | None = Field(default=None, ge=0)
    current_a: float | None = Field(default=None, ge=0)
    arc_length_correction_pct: float | None = None
    robot_speed_cm_min: float | None = Field(default=None, ge=0)
    synergic_law: str | None = Field(default=None, max_length=200)
    joint_type: str | None = Field(default=None, max_length=64)
    mm_per_px: float | None = Field(default=None, gt=0, le=MAX_MM_PER_PX)
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


class SequenceOut(SequenceIn):
    model_config = ConfigDict(from_attributes=True)

    id: int
    created_at: dt.datetime
    frame_count: int = 0


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


class LabelState(BaseModel):
    status: LabelStatus
    revision: int
    updated_at: dt.datetime


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


class IngestOut(BaseModel):
    """What became of each uploaded file."""

    stored: list[FrameOut]
    duplicates: list[Duplicate]
    rejected: list[Rejected]


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


class FramesDeleteIn(InputModel):
    frame_ids: list[Id] = Field(min_length=1, max_length=10_000)
    force: bool = Field(default=False, description="Also delete frames with reviewed labels.")
