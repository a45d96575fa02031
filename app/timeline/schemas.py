"""Payloads of the timeline: one weld run's pool geometry per frame."""

from __future__ import annotations

from pydantic import BaseModel, Field


class FrameGeometry(BaseModel):
    frame_id: int
    frame_index: int | None
    timestamp_s: float | None
    status: str
    source: str | None = Field(
        description="`label` (reviewed), the proposal's source key, or null (nothing yet)."
    )
    confidence: float | None = Field(description="The proposal's confidence; null for labels.")
    area_px: int | None
    length_px: float | None = Field(description="Extent along the run's travel axis.")
    width_px: float | None = Field(description="Extent across it.")
    centroid: list[float] | None
    keypoints: list[list[float]]
    area_mm2: float | None
    length_mm: float | None
    width_mm: float | None
    missing_file: str | None = Field(
        None, description="Why the frame has no geometry when its mask file is lost."
    )
    classes: dict[str, ClassFigures] = Field(
        default_factory=dict, description="The label's other classes, by name (none: absent)."
    )
    tags: list[str] = Field(default_factory=list, description="The label's frame tags.")


class ClassFigures(BaseModel):
    count: int = Field(description="The class's objects on the frame's label.")
    area_px: int | None = Field(description="Their areas summed (mask and instances classes).")
    area_mm2: float | None
    points: dict[str, list[float]] = Field(
        description="A points class: each named point, the mean over its objects (px)."
    )


class ConfiguredClass(BaseModel):
    name: str
    kind: str
    point_names: list[str] | None


class Timeline(BaseModel):
    sequence_id: int
    name: str
    mm_per_px: float | None
    travel_deg: float | None = Field(
        description="The travel axis in the image (0° right, 90° down)."
    )
    travel_source: str | None
    process: dict[str, float | str | None]
    frames: list[FrameGeometry]
    classes: list[ConfiguredClass] = Field(
        default_factory=list, description="The configured classes beside the pool."
    )
    frame_tags: list[str] = Field(default_factory=list, description="The configured tags.")
