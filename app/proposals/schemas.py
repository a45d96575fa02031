"""Payloads of proposals: one proposal of a frame, with its mask, and a frame's list."""

from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, Field


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
