"""What an import is asked to do (``ImportOptions``) and what it did (``ImportReport``)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from app.core.errors import InvalidInputError
from weldpool_core.annotations import READERS, Refusal

MAX_LISTED = 1000
"""Most skipped or refused items a job's result lists one by one (the rest are counted)."""

KEYPOINT_ROLES = ("validation", "label")
"""What a file's hand-placed pool keypoints become: validation keypoints (the frame joins the
validation split and does not train), or the label's own keypoints (it trains on them)."""


CLASS_OUTCOMES = {
    "kept": "",
    "unknown": "Skipped {} shape(s) of classes the label configuration does not have",
    "no_area": "Skipped {} shape(s) of configured classes that have no area to keep",
    "no_points": "Skipped {} shape(s) of configured points classes that are not points",
    "without_pool": (
        "Skipped {} shape(s) of other classes on images without a pool (a reviewed label is "
        "the pool's mask first: the teacher, student and gate learn from it, and an empty "
        "one would count as a reviewed pool)"
    ),
    "unknown_tags": "Skipped {} frame tag(s) the label configuration does not have",
    "attributes_left_out": (
        "Left out {} attribute value(s) the label configuration does not define or allow"
    ),
}
"""What became of a file's regions of classes other than the pool, and how ``skipped`` says it."""


@dataclass(frozen=True)
class ImportOptions:
    format: str
    sequence_id: int | None = None
    overwrite: bool = False
    category: str | None = None
    max_pixels: int = 25_000_000
    keypoints: str = "validation"  # KEYPOINT_ROLES
    review_stage: bool = False  # settings.review_stage: labels go through ``saved_review``
    class_map: dict[str, str] = field(default_factory=dict)  # the file's class → ours


@dataclass
class ImportReport:
    """What an import did: frames stored, labels and validation keypoints written, and every
    item it skipped or refused, with why."""

    frames: int = 0
    labels: int = 0
    keypoints: int = 0
    skipped: list[Refusal] = field(default_factory=list)
    refused: list[Refusal] = field(default_factory=list)
    classes: dict[str, Counter[str]] = field(
        default_factory=lambda: {k: Counter() for k in CLASS_OUTCOMES}
    )
    """Regions of classes other than the pool, by outcome (``CLASS_OUTCOMES``) and class."""

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
            "classes": {k: dict(sorted(v.items())) for k, v in self.classes.items()},
        }

    def skip_classes(self, source: str) -> None:
        """One line in ``skipped`` for each outcome of other classes' regions not kept."""
        for outcome, why in CLASS_OUTCOMES.items():
            counts = self.classes[outcome]
            if outcome != "kept" and counts:
                listed = ", ".join(f"{name} ×{n}" for name, n in counts.most_common())
                total = sum(counts.values())
                self.skipped.append(Refusal(source, f"{why.format(total)}: {listed}."))


def checked_class_map(text: str | None) -> dict[str, str]:
    """``file=ours,other=ours`` (the CLI's and the form's mapping of class names) as a dict."""
    mapping: dict[str, str] = {}
    for pair in (text or "").split(","):
        if not pair.strip():
            continue
        foreign, _, ours = pair.partition("=")
        if not foreign.strip() or not ours.strip():
            raise InvalidInputError(
                f"The class mapping {pair.strip()!r} is not file_name=our_name."
            )
        mapping[foreign.strip()] = ours.strip()
    if len(mapping) > 200:
        raise InvalidInputError("A class mapping names at most 200 classes.")
    return mapping


def checked_format(name: str) -> str:
    """``name`` when it is a label format, else a one-sentence error."""
    if name not in READERS:
        raise InvalidInputError(
            f"There is no label format {name!r}; use one of {', '.join(READERS)}."
        )
    return name
