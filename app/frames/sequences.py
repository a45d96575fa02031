"""Weld runs (sequences): create, find, rename, list, count their frames."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.bounds import MAX_MM_PER_PX
from app.core.db import commit_or_conflict
from app.core.errors import ConflictError, InvalidInputError, NotFoundError
from app.core.models import Frame, Sequence, User
from weldpool_core.geometry import scale_from_points


def create_sequence(session: Session, values: dict[str, Any], user: User | None) -> Sequence:
    """A new weld run; names are unique."""
    if session.scalar(sa.select(Sequence.id).where(Sequence.name == values["name"])):
        raise ConflictError(f"There is already a sequence named {values['name']!r}.")
    sequence = Sequence(**values, created_by_id=user.id if user else None)
    session.add(sequence)
    commit_or_conflict(session, f"There is already a sequence named {values['name']!r}.")
    return sequence


def get_sequence(session: Session, sequence_id: int) -> Sequence:
    # A query, not session.get: a run this session loaded and another deleted since must read
    # as gone, not raise on the refresh of its expired row.
    sequence = session.scalar(sa.select(Sequence).where(Sequence.id == sequence_id))
    if sequence is None:
        raise NotFoundError(f"There is no sequence {sequence_id}.")
    return sequence


def sequence_by_name(session: Session, name: str, user: User | None) -> Sequence:
    """The sequence called ``name``, created when missing (command-line import)."""
    sequence = session.scalar(sa.select(Sequence).where(Sequence.name == name))
    return sequence or create_sequence(session, {"name": name}, user)


def unique_sequence_name(session: Session, base: str) -> str:
    """``base``, or ``base (2)``, ``base (3)``… whichever is free."""
    taken = set(session.scalars(sa.select(Sequence.name).where(Sequence.name.like(f"{base}%"))))
    name, number = base, 1
    while name in taken:
        number += 1
        name = f"{base} ({number})"
    return name


def update_sequence(session: Session, sequence: Sequence, values: dict[str, Any]) -> Sequence:
    """Change a run's fields; ``scale_points`` (``{"points": [[x, y], [x, y]],
    "distance_mm": d}``) sets ``mm_per_px`` from two points a known distance apart."""
    values = dict(values)
    if (scale := values.pop("scale_points", None)) is not None:
        first, second = scale["points"]
        mm_per_px = scale_from_points(tuple(first), tuple(second), scale["distance_mm"])
        if mm_per_px > MAX_MM_PER_PX:
            raise InvalidInputError(
                f"That is {mm_per_px:.3g} mm per pixel, more than {MAX_MM_PER_PX:g} mm per "
                "pixel; check the distance (millimetres) and the two points."
            )
        values["mm_per_px"] = mm_per_px
    renamed = "name" in values and values["name"] != sequence.name
    if renamed and session.scalar(sa.select(Sequence.id).where(Sequence.name == values["name"])):
        raise ConflictError(f"There is already a sequence named {values['name']!r}.")
    for key, value in values.items():
        setattr(sequence, key, value)
    commit_or_conflict(session, f"There is already a sequence named {values.get('name')!r}.")
    return sequence


def frame_counts(session: Session, sequence_ids: Iterable[int]) -> dict[int, int]:
    rows = session.execute(
        sa.select(Frame.sequence_id, sa.func.count())
        .where(Frame.sequence_id.in_(list(sequence_ids)))
        .group_by(Frame.sequence_id)
    )
    return {sequence_id: count for sequence_id, count in rows if sequence_id is not None}


def list_sequences(session: Session) -> list[Sequence]:
    return list(session.scalars(sa.select(Sequence).order_by(Sequence.id.desc())))
