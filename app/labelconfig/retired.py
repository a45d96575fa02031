"""What a label holds that the configuration no longer accepts (objects of a class removed or
given another kind with ``force``, frame tags and attributes no longer configured), and the one
rule of a save for them: they stay stored, whatever the save sends, until it names them in
``remove_retired``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from app.core.errors import InvalidInputError
from app.labelconfig.schemas import POOL
from app.labelconfig.service import (
    Current,
    checked_frame_fields,
    checked_objects,
    valid_attributes,
)


@dataclass(frozen=True)
class Retired:
    """Retired parts of a label: positions in its ``objects``, tag names, attribute names."""

    objects: list[int] = field(default_factory=list)
    tags: list[str] = field(default_factory=list)
    attributes: list[str] = field(default_factory=list)


def object_retired(classes: dict[str, dict[str, Any]], item: dict[str, Any]) -> bool:
    """Whether the configuration no longer accepts stored ``item``: its class is gone, or now
    of the other shape (a points class's object holds a region, or a region class's points)."""
    spec = classes.get(str(item.get("class")))
    if spec is None or spec["name"] == POOL:
        return True
    return (spec["kind"] == "points") != ("points" in item)


def retired(
    config: Current, objects: list[dict[str, Any]] | None, frame_tags: dict[str, Any] | None
) -> Retired:
    """What of a stored label's ``objects`` and ``frame_tags`` the configuration retired: an
    attribute is retired when its name, or its value, is no longer accepted."""
    classes = config.classes()
    known = {t.casefold() for t in config.config.get("frame_tags", [])}
    frame = {"name": "the frame", "attributes": config.config.get("frame_attributes", [])}
    held = frame_tags or {}
    attributes = held.get("attributes", {})
    accepted = valid_attributes(frame, attributes)
    return Retired(
        objects=[i for i, item in enumerate(objects or []) if object_retired(classes, item)],
        tags=[t for t in held.get("tags", []) if t.casefold() not in known],
        attributes=[name for name in attributes if name not in accepted],
    )


@dataclass(frozen=True)
class Save:
    """What a save sends of the classes beside the pool (None: as the label holds it) and
    which retired parts it removes (positions and names as ``retired`` lists them)."""

    objects: list[dict[str, Any]] | None = None
    tags: list[str] | None = None
    attributes: dict[str, Any] | None = None
    remove: Retired = field(default_factory=Retired)

    def columns(
        self,
        config: Current,
        objects: list[dict[str, Any]] | None,
        frame_tags: dict[str, Any] | None,
        height: int,
        width: int,
    ) -> dict[str, Any]:
        """The label's new ``objects`` and ``frame_tags`` from the held ones: what is sent is
        checked against ``config`` (a copy of a retired part, as read, counts as kept), what is
        not stays; retired parts stay unless removed."""
        now = retired(config, objects, frame_tags)
        _check_removal(now, self.remove)
        held_objects, held = objects or [], frame_tags or {}
        held_attributes = held.get("attributes", {})
        old = [held_objects[i] for i in now.objects if i not in self.remove.objects]
        old_tags = [t for t in now.tags if t not in self.remove.tags]
        old_attributes = {
            n: held_attributes[n] for n in now.attributes if n not in self.remove.attributes
        }
        if self.objects is None:  # as held, in their order, less the retired ones removed
            kept = [o for i, o in enumerate(held_objects) if i not in self.remove.objects]
        else:
            given = [o for o in self.objects if o not in old]
            kept = (checked_objects(config, given, height, width) or []) + old
        tags = [t for t in held.get("tags", []) if t not in now.tags]
        if self.tags is not None:
            tags = [t for t in self.tags if t not in old_tags]
        attributes = {k: v for k, v in held_attributes.items() if k not in now.attributes}
        if self.attributes is not None:
            attributes = {
                k: v for k, v in self.attributes.items() if old_attributes.get(k, ...) != v
            }
        fields = checked_frame_fields(config, tags, attributes) or {"tags": [], "attributes": {}}
        fields = {
            "tags": sorted(set(fields["tags"]) | set(old_tags)),
            "attributes": old_attributes | fields["attributes"],
        }
        has_fields = fields["tags"] or fields["attributes"]
        return {"objects": kept or None, "frame_tags": fields if has_fields else None}


def _check_removal(now: Retired, remove: Retired) -> None:
    """A one-sentence 400 when a save removes what the label does not hold retired."""
    for position in remove.objects:
        if position not in now.objects:
            raise InvalidInputError(
                f"Object {position} of the label is not of a class the configuration removed; "
                "leave it out of objects to remove it."
            )
    for tag in remove.tags:
        if tag not in now.tags:
            raise InvalidInputError(f"The label holds no frame tag {tag!r} that was removed.")
    for name in remove.attributes:
        if name not in now.attributes:
            raise InvalidInputError(
                f"The label holds no frame attribute {name!r} that was removed."
            )
