"""Payloads of the teacher: a teacher run asked for, a frame's embedding state."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from app.core.bounds import Id, InputModel
from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS, PromptName


class TeacherRunIn(InputModel):
    """Which frames the teacher should propose masks for."""

    frame_ids: list[Id] | None = Field(default=None, max_length=100_000)
    sequence_id: Id | None = None
    prompts: PromptName = DEFAULT_PROMPTS
    force: bool = Field(default=False, description="Propose again for frames already seen.")


class EmbeddingOut(BaseModel):
    state: Literal["ready", "computing", "busy", "cold"] = Field(
        description="ready: the next click reads it from memory; computing: on its way; busy: "
        "not started, as many are being made as the budget allows (ask again); cold: neither."
    )
    elapsed_ms: float | None = Field(default=None, description="Since it was asked for.")
    expected_ms: float | None = Field(
        default=None, description="The median of the last embeddings' times here."
    )
