"""Where the learned classes' geometry sits in the OPC UA address space (``opcua``).

A student that learned other classes beside the pool adds, for the classes the stream carries
(``CellInfo.classes``: those ``--classes`` chose), a folder ``Classes`` under ``WeldPool`` with
one object per class, browse name the class's name:

- a points class: one object per named point, with ``X`` and ``Y`` (Double, frame pixels);
- a mask or instances class: ``AreaPx`` (Double, px²; 0 for an empty mask) and ``CentroidX``,
  ``CentroidY`` (Double, frame pixels).

Node ids are the browse path joined by dots: ``WeldPool.Classes``, ``WeldPool.Classes.wire``,
``WeldPool.Classes.wire.AreaPx``, ``WeldPool.Classes.torch.tip.X`` (names verbatim, as the label
configuration spells them). A value the frame does not have (a point not seen, the centroid of an
empty mask) is written with the status ``BadNoData`` and no value, as the pool's are; each is
written with the pool's variables of the same frame and carries its capture time. A student
without classes, or ``--classes none``, has no ``Classes`` folder.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from weldpool_core.student.classes import LearnedClass

FOLDER = "Classes"


@dataclass(frozen=True)
class ClassObject:
    """An object of the ``Classes`` folder: a class, or a named point of a points class."""

    path: tuple[str, ...]
    """Browse names below ``WeldPool``, e.g. ``("Classes", "torch", "tip")``."""
    description: str


@dataclass(frozen=True)
class ClassVariable:
    """A Double variable of a class, and where its value sits in the record's ``classes``."""

    path: tuple[str, ...]
    unit: str
    description: str
    learned: str
    """The class's name: its key in the record's ``classes``."""
    key: str
    """The point's name, ``area_px`` or ``centroid``."""
    index: int | None = None
    """0 (x) or 1 (y) of a pair; None for a number."""

    def value(self, geometry: Mapping[str, Any] | None) -> float:
        """This variable's value in a record's class geometry (NaN where the frame has none)."""
        found = (geometry or {}).get(self.learned) or {}
        value = found.get(self.key)
        if value is not None and self.index is not None:
            value = value[self.index]
        return math.nan if value is None else float(value)


def class_layout(
    classes: Sequence[LearnedClass],
) -> tuple[tuple[ClassObject, ...], tuple[ClassVariable, ...]]:
    """The objects (parents first) and variables of ``classes`` (none without classes)."""
    if not classes:
        return (), ()
    objects = [ClassObject((FOLDER,), "The learned classes beside the pool, one object each.")]
    variables: list[ClassVariable] = []
    for item in classes:
        here = (FOLDER, item.name)
        if not item.segments:
            objects.append(ClassObject(here, f"The points class {item.name!r}: its named points."))
            for point in item.points:
                objects.append(
                    ClassObject((*here, point), f"The point {point!r} (no data where not seen).")
                )
                for index, axis in enumerate(("X", "Y")):
                    variables.append(
                        ClassVariable(
                            (*here, point, axis),
                            "px",
                            f"The point's {'column' if index == 0 else 'row'} in the frame.",
                            item.name,
                            point,
                            index,
                        )
                    )
            continue
        objects.append(ClassObject(here, f"The {item.kind} class {item.name!r}: its region."))
        variables.append(
            ClassVariable((*here, "AreaPx"), "px²", "The class's area.", item.name, "area_px")
        )
        for index, (name, axis) in enumerate((("CentroidX", "column"), ("CentroidY", "row"))):
            variables.append(
                ClassVariable(
                    (*here, name),
                    "px",
                    f"The class's centroid, frame {axis} (none for an empty mask).",
                    item.name,
                    "centroid",
                    index,
                )
            )
    return tuple(objects), tuple(variables)
