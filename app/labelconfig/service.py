"""The label configuration in force (the newest ``LabelConfig`` row, else the pool alone), a
new version of it (admins; 409 on a stale version or, unless forced, on classes whose objects
labels still hold), and the one check of a label's objects, tags and attributes against it."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import ConflictError, InvalidInputError
from app.core.models import Label, LabelConfig, User
from app.labelconfig.schemas import POOL, LabelConfigIn, builtin
from weldpool_core.io import decode_mask_png
from weldpool_core.outline import coco_mask, rle_mask

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

MAX_OBJECTS = 1000
"""Most objects of other classes one label may hold."""
MAX_OBJECT_POLYGONS = 64
MAX_OBJECT_VERTICES = 20_000
"""Most vertices of one object's polygons in all."""


@dataclass(frozen=True)
class Current:
    """The configuration in force: its version (0: never configured) and body."""

    version: int
    config: dict[str, Any]
    user: str | None = None
    row: LabelConfig | None = None

    def classes(self) -> dict[str, dict[str, Any]]:
        return {c["name"]: c for c in self.config["classes"]}


def current(session: Session) -> Current:
    row = session.scalar(sa.select(LabelConfig).order_by(LabelConfig.version.desc()).limit(1))
    if row is None:
        return Current(0, builtin())
    user = session.get(User, row.user_id) if row.user_id is not None else None
    return Current(row.version, row.config, user.username if user else None, row)


def save(session: Session, user: User, body: LabelConfigIn) -> Current:
    """A new version from ``body`` (edited from ``body.version``): 409 when another was saved
    since, or when a class that labels hold objects of would go or change kind (unless
    ``force``: the objects stay stored, listed on their labels, and are no longer accepted)."""
    now = current(session)
    if body.version != now.version:
        raise _stale(now)
    config = body.model_dump(exclude={"version", "force"}, exclude_none=True)
    if not body.force:
        _refuse_orphans(session, now.classes(), {c["name"]: c for c in config["classes"]})
    session.add(LabelConfig(version=now.version + 1, config=config, user_id=user.id))
    try:
        session.commit()
    except sa.exc.IntegrityError:  # another admin saved the same version first
        session.rollback()
        raise _stale(current(session)) from None
    return current(session)


class StaleConfig(ConflictError):
    """A configuration saved from a version that is no longer the newest."""

    def __init__(self, now: Current) -> None:
        super().__init__(
            f"The label configuration was changed by {now.user or 'someone else'} (now at "
            f"version {now.version}); reload it and apply your change again."
        )
        self.extra = {"version": now.version}


def _stale(now: Current) -> StaleConfig:
    return StaleConfig(now)


def _refuse_orphans(
    session: Session, before: dict[str, dict[str, Any]], after: dict[str, dict[str, Any]]
) -> None:
    gone = {
        name
        for name, spec in before.items()
        if name not in after or after[name]["kind"] != spec["kind"]
    }
    if not gone:
        return
    held: Counter[str] = Counter()
    for objects in session.scalars(sa.select(Label.objects).where(Label.objects.is_not(None))):
        held.update({o.get("class") for o in objects or [] if o.get("class") in gone})
    if held:
        name, labels = sorted(held.items())[0]
        raise ConflictError(
            f"{labels} label(s) hold objects of the class {name!r}, which this change removes "
            "or changes the kind of; keep it, or send force: true to leave those objects unused."
        )


# --- a label's objects, tags and attributes -----------------------------------------------------


def checked_frame_fields(
    config: Current, tags: list[str], attributes: dict[str, Any]
) -> dict[str, Any] | None:
    """A label's ``frame_tags`` column: tags the configuration lists, attributes it defines."""
    known = {t.casefold(): t for t in config.config.get("frame_tags", [])}
    for tag in tags:
        if tag.casefold() not in known:
            raise InvalidInputError(
                f"There is no frame tag {tag!r} in the label configuration; add it there first."
            )
    specs = {a["name"]: a for a in config.config.get("frame_attributes", [])}
    values = _attributes(specs, attributes, "the frame")
    chosen = sorted({known[t.casefold()] for t in tags})
    return {"tags": chosen, "attributes": values} if chosen or values else None


def checked_objects(
    config: Current, objects: list[dict[str, Any]], height: int, width: int
) -> list[dict[str, Any]] | None:
    """Objects of the configured classes other than the pool, as stored: a ``mask`` class's
    mask (at most one per frame) and an ``instances`` object's region as compressed RLE with
    area and box (``polygons`` kept besides), a ``points`` object's named points inside the
    frame; each with attributes its class defines. Anything else: a one-sentence 400."""
    if len(objects) > MAX_OBJECTS:
        raise InvalidInputError(f"A label holds at most {MAX_OBJECTS} objects.")
    classes = config.classes()
    stored, masks = [], set()
    for number, item in enumerate(objects, 1):
        if not isinstance(item, dict) or not isinstance(item.get("class"), str):
            raise InvalidInputError(f"Object {number} names no class.")
        name = item["class"]
        spec = classes.get(name)
        if spec is None or name == POOL:
            raise InvalidInputError(_unknown(name, classes))
        if spec["kind"] == "mask":
            if name in masks:
                raise InvalidInputError(f"The mask class {name!r} has one mask per frame.")
            masks.add(name)
        kept: dict[str, Any] = {"class": name}
        if spec["kind"] == "points":
            kept["points"] = _points(item.get("points"), spec, height, width)
        else:
            kept |= _region(item, name, height, width)
        given = item.get("attributes", {})
        values = _attributes({a["name"]: a for a in spec.get("attributes", [])}, given, name)
        if values:
            kept["attributes"] = values
        stored.append(kept)
    return stored or None


def _unknown(name: str, classes: dict[str, Any]) -> str:
    if name == POOL:
        return "The pool is the label's mask and keypoints, not one of its objects."
    others = ", ".join(repr(n) for n in classes if n != POOL) or "none yet"
    return f"There is no class {name!r} in the label configuration (its other classes: {others})."


def valid_attributes(spec: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """The attributes among ``given`` that class ``spec`` defines, with a value it allows
    (an import keeps those and leaves the rest out)."""
    specs = {a["name"]: a for a in spec.get("attributes", [])}
    kept: dict[str, Any] = {}
    for key, value in given.items():
        try:
            kept |= _attributes(specs, {key: value}, spec["name"])
        except InvalidInputError:
            continue
    return kept


def _attributes(specs: dict[str, Any], given: Any, owner: str) -> dict[str, Any]:
    """``given`` ({name: value}) checked against the attribute ``specs`` of ``owner``."""
    if not isinstance(given, dict):
        raise InvalidInputError(f"The attributes of {owner} are not an object of names.")
    values: dict[str, Any] = {}
    for key, value in given.items():
        spec = specs.get(key)
        if spec is None:
            raise InvalidInputError(f"{owner.capitalize()} has no attribute {key!r}.")
        values[key] = _attribute_value(spec, value, owner)
    return values


def _attribute_value(spec: dict[str, Any], value: Any, owner: str) -> Any:
    kind, name = spec["type"], spec["name"]
    if kind == "choice" and value in spec["options"]:
        return value
    if kind == "flag" and isinstance(value, bool):
        return value
    if kind == "text" and isinstance(value, str) and len(value) <= 1000:
        return value
    if kind == "number" and _finite(value):
        low, high = spec.get("min"), spec.get("max")
        if (low is None or value >= low) and (high is None or value <= high):
            return value
    wanted = {
        "choice": f"one of {', '.join(map(repr, spec.get('options') or []))}",
        "flag": "true or false",
        "text": "text of up to 1,000 characters",
        "number": "a number"
        + (f" from {spec['min']:g}" if spec.get("min") is not None else "")
        + (f" to {spec['max']:g}" if spec.get("max") is not None else ""),
    }[kind]
    raise InvalidInputError(f"The attribute {name!r} of {owner} is {wanted}, not {value!r}.")


def _finite(value: Any) -> bool:
    """A JSON number that is a finite float (not a bool, not an integer too large for one)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _points(given: Any, spec: dict[str, Any], height: int, width: int) -> dict[str, list[float]]:
    name = spec["name"]
    if not isinstance(given, dict) or not given:
        raise InvalidInputError(f"A {name!r} object gives its points as {{name: [x, y]}}.")
    allowed = spec.get("point_names")
    points = {}
    for key, xy in given.items():
        if allowed is not None and key not in allowed:
            raise InvalidInputError(
                f"The class {name!r} has no point {key!r} (its points: {', '.join(allowed)})."
            )
        if not isinstance(xy, list | tuple) or len(xy) != 2 or not all(map(_finite, xy)):
            raise InvalidInputError(f"The point {key!r} of {name!r} is not [x, y].")
        x, y = float(xy[0]), float(xy[1])
        if not (0 <= x <= width and 0 <= y <= height):
            raise InvalidInputError(
                f"The point {key!r} of {name!r} at ({x:g}, {y:g}) lies outside the "
                f"{width}×{height} frame."
            )
        points[str(key)] = [x, y]
    return points


def _region(item: dict[str, Any], name: str, height: int, width: int) -> dict[str, Any]:
    """A mask or instance object's region (one of ``rle``, ``mask_png``, ``polygons``)."""
    given = [k for k in ("rle", "mask_png", "polygons") if item.get(k) is not None]
    if len(given) != 1:
        raise InvalidInputError(
            f"A {name!r} object gives its region as one of rle, mask_png or polygons."
        )
    polygons = None
    if given[0] == "rle":
        mask = _rle(item["rle"], height, width)
    elif given[0] == "mask_png":
        mask = decode_mask_png(_base64(item["mask_png"]), shape=(height, width))
    else:
        polygons = _polygons(item["polygons"], name, height, width)
        mask = _filled(polygons, height, width)
    if mask.shape != (height, width):
        raise InvalidInputError(
            f"The {name!r} mask is {mask.shape[1]}×{mask.shape[0]}; the frame is {width}×{height}."
        )
    if not mask.any():
        raise InvalidInputError(f"The region of a {name!r} object is empty.")
    coco = coco_mask(mask)
    region: dict[str, Any] = {"rle": coco.rle, "area": coco.area, "bbox": coco.bbox}
    if polygons is not None:
        region["polygons"] = polygons
    return region


def _rle(rle: Any, height: int, width: int) -> NDArray[np.bool_]:
    if (
        not isinstance(rle, dict)
        or not isinstance(rle.get("counts"), str)
        or rle.get("size") != [height, width]
    ):
        raise InvalidInputError(
            f"An rle is COCO's compressed {{'size': [{height}, {width}], 'counts': str}}."
        )
    try:
        return rle_mask({"size": [height, width], "counts": rle["counts"]})
    except (ValueError, TypeError, UnicodeEncodeError):
        raise InvalidInputError("An rle's counts cannot be decoded.") from None


def _base64(text: Any) -> bytes:
    import base64
    import binascii

    try:
        return base64.b64decode(text if isinstance(text, str) else "", validate=True)
    except (binascii.Error, ValueError):
        raise InvalidInputError("A mask_png is not base64.") from None


def _polygons(given: Any, name: str, height: int, width: int) -> list[list[list[float]]]:
    if not isinstance(given, list) or not 1 <= len(given) <= MAX_OBJECT_POLYGONS:
        raise InvalidInputError(
            f"A {name!r} object's polygons are 1 to {MAX_OBJECT_POLYGONS} lists of [x, y]."
        )
    polygons, total = [], 0
    for polygon in given:
        total += len(polygon) if isinstance(polygon, list) else 0
        if not isinstance(polygon, list) or len(polygon) < 3 or total > MAX_OBJECT_VERTICES:
            raise InvalidInputError(
                f"A {name!r} polygon has 3 or more [x, y] points "
                f"({MAX_OBJECT_VERTICES:,} in all at most)."
            )
        points = _points({str(i): p for i, p in enumerate(polygon)}, {"name": name}, height, width)
        polygons.append(list(points.values()))
    return polygons


def _filled(polygons: list[list[list[float]]], height: int, width: int) -> NDArray[np.bool_]:
    from weldpool_core.outline import Polygon, fill_polygons

    mask = np.zeros((height, width), bool)
    for polygon in polygons:
        mask |= fill_polygons([Polygon([(x, y) for x, y in polygon])], height, width)
    return mask
