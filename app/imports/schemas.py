"""What an import is asked to do (``ImportOptions``) and what it did (``ImportReport``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from app.core.errors import InvalidInputError
from weldpool_core.annotations import READERS, Refusal

MAX_LISTED = 1000
"""Most skipped or refused items a job's result lists one by one (the rest are counted)."""

KEYPOINT_ROLES = ("validation", "label")
"""What a file's hand-placed pool keypoints become: validation keypoints (the frame joins the
validation split and does not train), or the label's own keypoints (it trains on them)."""


@dataclass(frozen=True)
class ImportOptions:
    format: str
    sequence_id: int | None = None
    overwrite: bool = False
    category: str | None = None
    max_pixels: int = 25_000_000
    keypoints: str = "validation"  # KEYPOINT_ROLES
    review_stage: bool = False  # settings.review_stage: labels go through ``saved_review``


@dataclass
class ImportReport:
    """What an import did: frames stored, labels and validation keypoints written, and every
    item it skipped or refused, with why."""

    frames: int = 0
    labels: int = 0
    keypoints: int = 0
    skipped: list[Refusal] = field(default_factory=list)
    refused: list[Refusal] = field(default_factory=list)

    def as_result(self) -> dict[str, Any]:
        def listed(items: list[Refusal]) -> list[dict[str, str]]:
            return [{"item": r.item, "reason": r.reason} for r in items[:MAX_LISTED]]

        return {
            "frames": self.frames,
            "labels": self.labels,
            "keypoints": self.keypoints,
            "skipped": listed(self.skipped),
            "skipped_count": len(self.skipped),
            "refused": listed(self.refused),
            "refused_count": len(self.refused),
        }


def checked_format(name: str) -> str:
    """``name`` when it is a label format, else a one-sentence error."""
    if name not in READERS:
        raise InvalidInputError(
            f"There is no label format {name!r}; use one of {', '.join(READERS)}."
        )
    return name
