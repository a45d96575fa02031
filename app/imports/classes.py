"""What an import keeps of a file's other classes and frame fields: each region or points object
of a configured class (under its mapped name), its attributes the class defines, the frame's
tags and attributes the configuration lists; everything else counted by why
(``ImportReport.classes``)."""

from __future__ import annotations

from typing import Any

from app.imports.schemas import ImportReport
from app.labelconfig import service as labelconfig
from app.labelconfig.schemas import MAX_OPTIONS, POOL
from weldpool_core.annotations import Parsed
from weldpool_core.annotations.shapes import ImportedLabel, OtherShape

REGION_KINDS = ("mask", "instances")


def sort_classes(
    parsed: Parsed, config: labelconfig.Current, mapping: dict[str, str], report: ImportReport
) -> None:
    """Each object of another class (under its mapped name) kept where the configuration has
    its class and its form fits the class's kind, else counted; each label's frame tags and
    attributes kept where the configuration lists them, else counted."""
    classes = config.classes()
    report.classes["without_pool"].update(mapping.get(n, n) for n in parsed.without_pool.elements())
    for label in parsed.labels:
        for other in label.others:
            other.name = mapping.get(other.name, other.name)
            spec = classes.get(other.name) if other.name != POOL else None
            if spec is not None:
                other.points = named_points(other.points, spec)
            outcome = _outcome(other, spec)
            report.classes[outcome][other.name] += 1
            if outcome == "kept" and spec is not None:
                other.kind = spec["kind"]
                given = coerced(spec.get("attributes", []), other.attributes)
                other.attributes = labelconfig.valid_attributes(spec, given)
                _count_left_out(report, other.name, given, other.attributes)
        _frame_fields(label, config.config, report)


def _outcome(other: OtherShape, spec: dict[str, Any] | None) -> str:
    if spec is None:
        return "unknown"
    if spec["kind"] == "points":
        return "kept" if other.points else "no_points"
    return "kept" if other.shape is not None else "no_area"


def named_points(
    points: dict[str, list[float]] | None, spec: dict[str, Any]
) -> dict[str, list[float]] | None:
    """A points object's points, those a file numbers in order (1, 2, …: CVAT without names,
    LabelMe) named by the class's own point names; those the class does not name left out (a
    class that does not fix its names: the first 64 with a name of 1–64 characters)."""
    names = spec.get("point_names")
    if points is None:
        return None
    if names is None:  # the file names them: names as a configuration's, as many as it may have
        named = {n.strip(): xy for n, xy in points.items() if 0 < len(n.strip()) <= 64}
        return dict(list(named.items())[:MAX_OPTIONS]) or None
    numbered = list(points) == [str(i) for i in range(1, len(points) + 1)]
    if numbered and len(points) <= len(names):
        return {names[i]: xy for i, xy in enumerate(points.values())}
    return {n: xy for n, xy in points.items() if n in names} or None


def _count_left_out(
    report: ImportReport, owner: str, given: dict[str, Any], kept: dict[str, Any]
) -> None:
    for name in given.keys() - kept.keys():
        report.classes["attributes_left_out"][f"{owner}.{name}"] += 1


def _frame_fields(label: ImportedLabel, config: dict[str, Any], report: ImportReport) -> None:
    """The label's tags as the configuration spells them (others counted), and its frame
    attributes the configuration defines with a value it allows (others counted)."""
    known = {t.casefold(): t for t in config.get("frame_tags", [])}
    tags = []
    for tag in label.tags[:MAX_OPTIONS]:  # no more than a configuration may list
        if tag.casefold() in known:
            tags.append(known[tag.casefold()])
        else:
            report.classes["unknown_tags"][tag[:64]] += 1
    label.tags = sorted(set(tags))
    specs = config.get("frame_attributes", [])
    given = coerced(specs, label.frame_attributes)
    label.frame_attributes = labelconfig.valid_attributes(
        {"name": "the frame", "attributes": specs}, given
    )
    _count_left_out(report, "frame", given, label.frame_attributes)


def frame_tags(label: ImportedLabel) -> dict[str, Any] | None:
    """The ``Label.frame_tags`` column of an imported label (sorted as ``sort_classes`` left
    them), as ``labelconfig.checked_frame_fields`` stores a saved one."""
    if not label.tags and not label.frame_attributes:
        return None
    return {"tags": label.tags, "attributes": label.frame_attributes}


def coerced(specs: list[dict[str, Any]], given: dict[str, Any]) -> dict[str, Any]:
    """``given`` with text values read as their attribute's type (a CVAT file's attributes are
    all text): ``true``/``false`` for a flag, a number for a number; others as they are."""
    types = {a["name"]: a["type"] for a in specs}
    values = {}
    for name, value in given.items():
        kind = types.get(name)
        if isinstance(value, str) and kind == "flag" and value.strip().lower() in FLAGS:
            value = FLAGS[value.strip().lower()]
        elif isinstance(value, str) and kind == "number":
            value = _number(value.strip(), value)
        values[name] = value
    return values


FLAGS = {"true": True, "false": False, "1": True, "0": False, "yes": True, "no": False}


def _number(text: str, fallback: Any) -> Any:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            continue
    return fallback
