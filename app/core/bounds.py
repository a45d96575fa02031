"""Bounds shared by every input of the API: ids, offsets, numbers, text and frame pixels.

Ids are PostgreSQL ``INTEGER`` columns (SQLite's are wider), so an id or offset above 2³¹ − 1
is refused with a 422 by the schema rather than reaching the database. Input bodies refuse
NaN and ±Infinity and text with a NUL character (PostgreSQL cannot store one). Coordinates in
frame pixels (clicks, boxes, keypoints, outline vertices) are checked against the frame they
address, so a request's work follows the frame's size rather than the numbers it sends.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Path, Query
from pydantic import BaseModel, ConfigDict, Field, field_validator

from app.core.errors import InvalidInputError

MAX_ID = 2**31 - 1
"""Largest id or offset the API accepts (PostgreSQL INTEGER)."""

Id = Annotated[int, Field(ge=1, le=MAX_ID)]
IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]
MAX_MM_PER_PX = 100.0
"""The largest image scale a weld run may have (a pool camera sees far less than 100 mm a pixel)."""
MIN_MM_PER_PX = 1e-6
"""The smallest image scale a weld run may have (a nanometre a pixel, far finer than any camera
sees a pool); with ``MAX_MM_PER_PX`` the physical range of a run's scale."""
XY = Annotated[list[float], Field(min_length=2, max_length=2, description="[x, y] in pixels")]
OffsetQuery = Annotated[int, Query(ge=0, le=MAX_ID)]


def check_in_frame(x: float, y: float, width: int, height: int, what: str) -> None:
    """Refuse a point ``what`` outside the ``width``×``height`` frame (its edges are inside)."""
    if not (0 <= x <= width and 0 <= y <= height):
        raise InvalidInputError(
            f"The {what} ({x:g}, {y:g}) lies outside the {width}×{height} frame."
        )


def _has_nul(value: Any) -> bool:
    if isinstance(value, str):
        return "\x00" in value
    if isinstance(value, dict):
        return any(_has_nul(k) or _has_nul(v) for k, v in value.items())
    if isinstance(value, list | tuple):
        return any(_has_nul(v) for v in value)
    return False


NO_NUL_PATTERN = "^[^\\x00]*$"
"""The schema's pattern for text (``app.core.openapi`` adds it to every string it documents)."""


class InputModel(BaseModel):
    """Base of request bodies: finite numbers only, no NUL in the text of any field
    (unknown fields are ignored, as before)."""

    model_config = ConfigDict(allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_nul(cls, value: Any) -> Any:
        if _has_nul(value):
            raise ValueError("text must not contain NUL characters")
        return value
