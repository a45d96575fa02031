"""Payloads of student training and model versions."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from app.core.bounds import Id, InputModel


class TrainIn(InputModel):
    """Options of a training job; the defaults suit a CPU worker."""

    epochs: int | None = Field(default=None, ge=1, le=1000)
    size: Literal["resnet18", "resnet34", "light"] | None = Field(
        default=None,
        description="Model size (default: the light student, which learns the real pool best "
        "from few labels and runs fastest; resnet18 / resnet34 start from ImageNet weights "
        "when they are on the machine).",
    )
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    pseudo_labels: bool = Field(
        default=False,
        description="Also learn from the teacher's proposals on frames nobody has labelled "
        "(the paper's distillation), when the teacher is confident of them; each weighs "
        "`pseudo_weight` × its confidence against 1 for a reviewed label.",
    )
    pseudo_min_confidence: float = Field(
        default=0.8,
        ge=0.0,
        le=1.0,
        description="Least teacher confidence (SAM2's predicted IoU × prompt stability).",
    )
    pseudo_weight: float = Field(default=0.5, gt=0.0, le=1.0)


class TrainingPlanOut(BaseModel):
    """What a training started now would learn from and be measured on."""

    labels: int = Field(description="Reviewed labels it would train on.")
    validation_frames: int = Field(description="Frames of the validation split it is measured on.")
    held_out: int = Field(
        description="Labels held out from training to measure it on (without a validation split)."
    )
    needed: int = Field(
        description="The fewest reviewed labels (outside the validation split) with which the "
        "promotion gate can measure the version: 1 with a validation split, 3 without."
    )
    warning: str | None = Field(
        description="Why the version could not be measured (too few labels), or null."
    )


class TrainCreated(TrainingPlanOut):
    """A training job, queued, with the plan it was started on."""

    job_id: int


class SequentialIn(InputModel):
    """Options of a sequential-cell training job."""

    steps: int | None = Field(
        default=None, ge=1, le=10_000, description="Optimiser steps (default 200)."
    )
    seed: int = Field(default=0, ge=0, le=2**31 - 1)


class StudentRunIn(InputModel):
    """Which frames the promoted student should propose for."""

    frame_ids: list[Id] | None = Field(default=None, max_length=100_000)
    sequence_id: Id | None = None


class ModelVersionOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    created_at: dt.datetime
    is_promoted: bool
    promoted_at: dt.datetime | None
    train_label_count: int
    metrics: dict[str, Any]
    curve: list[Any]
    config: dict[str, Any]
    job_id: int | None
    gate: dict[str, Any] | None = Field(
        default=None,
        description="The promotion gate's last verdict: `usable`, `promote`, `reason`, scores.",
    )
    sequential: dict[str, Any] | None = Field(
        default=None,
        description="Its sequential cell (for steadier live keypoints), null when it has none: "
        "`trained_at`, `job_id`, `windows`, `videos`, and `measured` — the cell against the "
        "per-frame student on the validation split's video frames (`per_frame_iou`, "
        "`sequential_iou`, `frames`) and on unlabelled windows (`per_frame_change`, "
        "`sequential_change`: the share of the mask that changes per frame, `windows`).",
    )
    int8: dict[str, Any] | None = Field(
        default=None,
        description="Its int8 student (`POST /models/{id}/int8`), null when it has none: "
        "`made_at`, `job_id`, the agreement with the float student on frames it was not "
        "calibrated on (`mean_iou`, `min_iou`, `keypoint_px`, `mask_difference`, "
        "`check_frames`, `calibration_frames`) and one frame's inference here on one thread "
        "(`float_ms`, `int8_ms`).",
    )
