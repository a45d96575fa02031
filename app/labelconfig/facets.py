"""A label's facets (``LabelFacet`` rows): the classes it holds (the pool where it has a mask),
its frame tags and its frame attributes' values, written by the one label writer in the
label's transaction; and the frames list's filters on them, checked against the label
configuration in force."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.errors import InvalidInputError
from app.core.models import Frame, LabelFacet
from app.labelconfig.schemas import POOL
from app.labelconfig.service import Current

CLASS, TAG, ATTR = "class", "tag", "attr"
MAX_VALUE = 200
"""A text attribute longer than this is not indexed (the list cannot filter on it)."""

Facet = tuple[str, str, str, int]
"""(kind, key, value, count)."""


def facet_text(value: Any) -> str | None:
    """An attribute's value as the facet stores it: ``true``/``false``, a number as its
    shortest decimal (``3`` for 3.0), text as it is; None where it cannot be filtered on."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        number = float(value)
        if not math.isfinite(number):
            return None
        return str(int(number)) if number.is_integer() and abs(number) < 1e15 else repr(number)
    if isinstance(value, str) and len(value) <= MAX_VALUE:
        return value
    return None


def label_facets(values: Mapping[str, Any]) -> list[Facet]:
    """The facets of a label's columns (``status``, ``mask_path``, ``objects``,
    ``frame_tags``): the pool where it has a mask, each other class with its object count,
    each tag, each attribute value that can be filtered on."""
    facets: list[Facet] = []
    if values.get("mask_path"):
        facets.append((CLASS, POOL, "", 1))
    held = Counter(
        str(o.get("class"))[:64]
        for o in values.get("objects") or []
        if isinstance(o, dict) and o.get("class") not in (None, POOL)
    )
    facets += [(CLASS, name, "", n) for name, n in sorted(held.items())]
    frame = values.get("frame_tags") or {}
    facets += [(TAG, str(tag)[:64], "", 1) for tag in sorted(set(frame.get("tags") or []))]
    for name, value in sorted((frame.get("attributes") or {}).items()):
        text = facet_text(value)
        if text is not None:
            facets.append((ATTR, str(name)[:64], text, 1))
    return facets


def index_label(session: Session, frame_id: int, values: Mapping[str, Any], *, new: bool) -> None:
    """Write the facets of the label ``values`` describe (the label writer's one call, in its
    transaction): a new label's rows are added to the session (flushed with the label, a
    batch's all at once), an updated one's replace the rows it had."""
    if not new:
        session.execute(sa.delete(LabelFacet).where(LabelFacet.frame_id == frame_id))
    session.add_all(
        LabelFacet(frame_id=frame_id, kind=kind, key=key, value=value, count=count)
        for kind, key, value, count in label_facets(values)
    )


# --- the frames list's filters -------------------------------------------------------------------


def _names(names: Iterable[str]) -> str:
    return ", ".join(repr(n) for n in names) or "none yet"


def _one_of(given: str, known: Iterable[str]) -> str | None:
    """The configured name ``given`` names, ignoring case."""
    return next((name for name in known if name.casefold() == given.casefold()), None)


def _has(kind: str, key: str, value: str = "") -> Any:
    facet = sa.select(LabelFacet.frame_id).where(
        LabelFacet.kind == kind, LabelFacet.key == key, LabelFacet.value == value
    )
    return Frame.id.in_(facet)


def _attribute_value(spec: dict[str, Any], text: str) -> str:
    """The facet text of a frame attribute's value as a filter gives it, or one sentence."""
    name, kind = spec["name"], spec["type"]
    if kind != "text":
        text = text.strip()
    if kind == "choice":
        option = _one_of(text, spec["options"])
        if option is None:
            raise InvalidInputError(
                f"The frame attribute {name!r} has no option {text!r} (its options: "
                f"{_names(spec['options'])})."
            )
        return option
    if kind == "flag":
        if text.lower() not in ("true", "false"):
            raise InvalidInputError(f"The frame attribute {name!r} is true or false.")
        return text.lower()
    if kind == "number":
        try:
            number = facet_text(float(text))
        except ValueError:
            number = None
        if number is None:
            raise InvalidInputError(f"The frame attribute {name!r} is a number, not {text!r}.")
        return number
    if len(text) > MAX_VALUE:
        raise InvalidInputError(f"A text filter is at most {MAX_VALUE} characters.")
    return text


def filter_conditions(
    config: Current,
    classes: Iterable[str] = (),
    tags: Iterable[str] = (),
    attributes: Iterable[str] = (),
) -> list[Any]:
    """The frames list's conditions: frames whose label holds every class (``pool``: a pool
    mask), every tag and every attribute value (``name:value``) given; a one-sentence 400
    naming the configured ones for a name the configuration does not have."""
    conditions = []
    known = [c["name"] for c in config.config["classes"]]
    for given in classes:
        name = _one_of(given, known)
        if name is None:
            raise InvalidInputError(
                f"There is no class {given!r} in the label configuration (its classes: "
                f"{_names(known)})."
            )
        conditions.append(_has(CLASS, name))
    frame_tags = config.config.get("frame_tags", [])
    for given in tags:
        tag = _one_of(given, frame_tags)
        if tag is None:
            raise InvalidInputError(
                f"There is no frame tag {given!r} in the label configuration (its tags: "
                f"{_names(frame_tags)})."
            )
        conditions.append(_has(TAG, tag))
    specs = {a["name"]: a for a in config.config.get("frame_attributes", [])}
    for given in attributes:
        name, colon, text = given.partition(":")
        if not colon:
            raise InvalidInputError(
                f"Give a frame attribute filter as name:value (attr=weather:rain), not {given!r}."
            )
        key = _one_of(name.strip(), specs)
        if key is None:
            raise InvalidInputError(
                f"There is no frame attribute {name.strip()!r} in the label configuration (its "
                f"frame attributes: {_names(specs)})."
            )
        conditions.append(_has(ATTR, key, _attribute_value(specs[key], text)))
    return conditions
