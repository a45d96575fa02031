"""Payloads of the review loop: teacher runs, proposals, clicks, labels, manual keypoints."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, Field, model_validator

from app.models import LabelStatus


class TeacherRunIn(BaseModel):
    """Which frames the teacher should propose masks for."""

    frame_ids: list[int] | None = Field(default=None, max_length=100_000)
    sequence_id: int | None = None
    prompts: Literal["none", "center", "heuristic"] = "heuristic"
    force: bool = Field(default=False, description="Propose again for frames already seen.")


class ProposalSummary(BaseModel):
    """One proposal of a frame and where it came from."""

    id: int
    frame_id: int
    source: str = Field(description="`teacher`, `student` or `propagated`.")
    source_key: str = Field(description="`teacher` or `<source>:<model id>`; pass as ?source=.")
    model_id: str = Field(description="The teacher's models and prompts, or the student version.")
    model_version_id: int | None
    job_id: int | None
    keypoints: list[list[float]]
    scores: dict[str, Any]
    created_at: dt.datetime
    chosen: bool = Field(description="Whether the policy shows this proposal for review.")


class ProposalOut(ProposalSummary):
    """A frame's proposal with its mask: the policy's pick unless one was asked for."""

    mask_png: str = Field(description="Single-channel PNG (0 / 255), base64.")
    prompts: dict[str, Any]
    timings: dict[str, Any]


class ProposalList(BaseModel):
    """Every proposal of a frame, newest first, and the policy that picks the shown one."""

    items: list[ProposalSummary]
    policy: dict[str, Any] = Field(
        description="`chosen` source key, `reason`, and each source's agreement with labels."
    )


class Point(BaseModel):
    x: float
    y: float
    positive: bool = True


class SegmentIn(BaseModel):
    """Clicks and/or a box in frame pixels, optionally refining a previous mask."""

    points: list[Point] = Field(default_factory=list, max_length=64)
    box: tuple[float, float, float, float] | None = Field(
        default=None, description="[x0, y0, x1, y1]"
    )
    mask_png: str | None = Field(
        default=None, description="A previous mask to refine (base64 PNG)."
    )


class SegmentOut(BaseModel):
    mask_png: str
    score: float = Field(description="SAM2's predicted IoU of the returned mask.")
    scores: list[float]
    elapsed_ms: float = Field(description="Server time for this click.")
    embedding: Literal["memory", "disk", "computed"]


class LabelIn(BaseModel):
    """A reviewer's verdict; ``base_revision`` is the revision you saw (0: no label yet)."""

    status: LabelStatus
    base_revision: int = Field(ge=0)
    mask_png: str | None = Field(default=None, description="A corrected mask (base64 PNG).")
    keypoints: list[list[float]] | None = None
    proposal_id: int | None = Field(
        default=None,
        ge=1,
        le=2**31 - 1,
        description="The proposal the label started from (default: the one the policy shows).",
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
    updated_by: str | None
    updated_at: dt.datetime


class LabelRevisionOut(BaseModel):
    revision: int
    status: LabelStatus
    keypoints: list[list[float]] | None
    has_mask: bool
    user: str | None
    created_at: dt.datetime


class KeypointsIn(BaseModel):
    keypoints: list[list[float]] = Field(min_length=1, max_length=64)


class KeypointsOut(BaseModel):
    frame_id: int
    keypoints: list[list[float]]
    updated_at: dt.datetime
