"""The label configuration's payloads: classes (the built-in pool and a lab's own), their
attributes, and the frame's tags and attributes; every check a configuration must pass."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from app.core.bounds import MAX_ID, InputModel

POOL = "pool"
"""The built-in class: the one the teacher proposes, the student learns and the gate judges."""
POOL_COLOR = "#ff8c00"
MAX_CLASSES = 64
MAX_ATTRIBUTES = 32
MAX_OPTIONS = 64
Name = Field(min_length=1, max_length=64, pattern=r"^[^\s].*[^\s]$|^[^\s]$")
"""A class, attribute, option, point or tag name: 1–64 characters, no space at either end."""


EXPORT_NAMES = {"weld_pool": "the pool", "frame_attributes": "the frame's attributes"}


def _unique(names: list[str], what: str) -> None:
    seen: set[str] = set()
    for name in names:
        key = name.casefold()
        if key in seen:
            raise ValueError(f"two {what} are named {name!r} (names are compared ignoring case)")
        seen.add(key)


class AttributeSpec(InputModel):
    """One attribute of a class's objects or of a frame: a ``choice`` among ``options``, a
    ``flag`` (true/false), a ``number`` (between ``min`` and ``max`` when given) or ``text``."""

    name: str = Name
    type: Literal["choice", "flag", "number", "text"]
    options: list[str] | None = Field(default=None, max_length=MAX_OPTIONS)
    min: float | None = None
    max: float | None = None

    @model_validator(mode="after")
    def _options_fit_the_type(self) -> AttributeSpec:
        if self.type == "choice":
            if not self.options:
                raise ValueError(f"the choice attribute {self.name!r} needs its options")
            for option in self.options:
                if not option.strip() or len(option) > 64:
                    raise ValueError(f"an option of {self.name!r} is empty or over 64 characters")
            _unique(self.options, f"options of {self.name!r}")
        elif self.options:
            raise ValueError(
                f"only a choice attribute has options ({self.name!r} is a {self.type})"
            )
        if (self.min is not None or self.max is not None) and self.type != "number":
            raise ValueError(f"only a number attribute has min and max ({self.name!r})")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"the attribute {self.name!r} has min above max")
        return self


class ClassSpec(InputModel):
    """One class: ``mask`` (one semantic mask per frame), ``instances`` (several objects, each
    its own region) or ``points`` (named points, ``point_names`` when the class fixes them)."""

    name: str = Name
    kind: Literal["mask", "instances", "points"]
    color: str | None = Field(default=None, pattern=r"^#[0-9a-fA-F]{6}$")
    hotkey: str | None = Field(default=None, min_length=1, max_length=1)
    attributes: list[AttributeSpec] = Field(default_factory=list, max_length=MAX_ATTRIBUTES)
    point_names: list[str] | None = Field(default=None, max_length=MAX_OPTIONS)

    @model_validator(mode="after")
    def _consistent(self) -> ClassSpec:
        _unique([a.name for a in self.attributes], f"attributes of {self.name!r}")
        if self.point_names is not None:
            if self.kind != "points":
                raise ValueError(f"only a points class names its points ({self.name!r})")
            _unique(self.point_names, f"points of {self.name!r}")
        if self.hotkey is not None and self.hotkey.isspace():
            raise ValueError(f"the hotkey of {self.name!r} is a space")
        return self


class LabelConfigBody(InputModel):
    """The classes and frame fields of a configuration (``pool`` is added when left out)."""

    classes: list[ClassSpec] = Field(default_factory=list, max_length=MAX_CLASSES)
    frame_tags: list[str] = Field(default_factory=list, max_length=MAX_OPTIONS)
    frame_attributes: list[AttributeSpec] = Field(default_factory=list, max_length=MAX_ATTRIBUTES)

    @field_validator("frame_tags")
    @classmethod
    def _tags(cls, tags: list[str]) -> list[str]:
        for tag in tags:
            if not tag.strip() or len(tag) > 64 or tag != tag.strip():
                raise ValueError("a frame tag is 1–64 characters without a space at either end")
        _unique(tags, "frame tags")
        return tags

    @model_validator(mode="after")
    def _classes(self) -> LabelConfigBody:
        _unique([c.name for c in self.classes], "classes")
        # CVAT's meta and YOLO's names are one list of labels: a tag and a class never share a
        # name, and the names the exports give the pool and the frame's attributes are taken.
        _unique([c.name for c in self.classes] + self.frame_tags, "classes or frame tags")
        for name in [c.name for c in self.classes] + self.frame_tags:
            if name.casefold() in EXPORT_NAMES:
                raise ValueError(
                    f"{name!r} is the name exports give {EXPORT_NAMES[name.casefold()]}"
                )
        _unique([a.name for a in self.frame_attributes], "frame attributes")
        _unique([c.hotkey for c in self.classes if c.hotkey], "hotkeys (one per class)")
        pool = next((c for c in self.classes if c.name.casefold() == POOL), None)
        if pool is None:
            self.classes.insert(0, ClassSpec(name=POOL, kind="mask", color=POOL_COLOR))
        elif pool.name != POOL or pool.kind != "mask":
            raise ValueError("the built-in class 'pool' keeps its name and its kind, mask")
        return self


REVIEW_KEYS = "1234567arsnmhfvlp[] "
"""The review page's own shortcuts (the page reads them from here): a class's hotkey is none of
them, or pressing it would never pick the class."""


class LabelConfigIn(LabelConfigBody):
    """A new configuration; ``version`` is the one it was edited from (0: the built-in pool
    alone); a stale one is a 409. ``force`` removes classes whose objects labels still hold."""

    version: int = Field(ge=0, le=MAX_ID)
    force: bool = False

    @model_validator(mode="after")
    def _free_hotkeys(self) -> LabelConfigIn:
        """Only a new configuration is held to it: one saved before the rule still reads."""
        for spec in self.classes:
            if spec.hotkey and spec.hotkey.lower() in REVIEW_KEYS:
                digits = [k for k in REVIEW_KEYS if k.isdigit()]
                others = ", ".join(k for k in REVIEW_KEYS if not k.isdigit() and k != " ")
                raise ValueError(
                    f"the hotkey {spec.hotkey!r} of {spec.name!r} is one of the review page's "
                    f"own shortcuts ({digits[0]}–{digits[-1]}, {others} and space); pick "
                    "another key"
                )
        return self


class LabelConfigOut(LabelConfigBody):
    version: int = Field(description="0: never configured (the pool alone).")
    updated_by: str | None = None
    updated_at: dt.datetime | None = None


def builtin() -> dict[str, Any]:
    """The configuration of an instance nobody configured: the pool alone."""
    return LabelConfigBody().model_dump(exclude_none=True)
