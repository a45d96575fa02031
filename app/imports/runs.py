"""The runs an import's new frames go to: the one asked for, else the runs a weldpool export
names (made with their process parameters), else one new run named after the import."""

from __future__ import annotations

import posixpath
from typing import Any

import sqlalchemy as sa
from pydantic import ValidationError
from sqlalchemy.orm import Session

from app.core.errors import ConflictError
from app.core.models import Sequence, User
from app.frames import sequences
from app.frames.schemas import SequenceIn
from weldpool_core.annotations import ImportedLabel, Refusal

RUN_NAME = 190
"""Longest run name an import makes (runs hold 200 characters; ``name (2)`` needs room)."""


class Runs:
    """The run each label's new frame goes to: the one asked for; else the run the label
    names (a weldpool export's, created with its process parameters when missing); else one
    new run named after the import, made when first needed."""

    def __init__(
        self,
        session: Session,
        name: str,
        sequence_id: int | None,
        user: User,
        refused: list[Refusal],
    ) -> None:
        self._session, self._user, self._refused = session, user, refused
        self._name = posixpath.splitext(posixpath.basename(name))[0][:RUN_NAME] or "import"
        self._fixed = sequence_id
        self._by_name: dict[str, int] = {}
        self._default: int | None = None

    @property
    def fixed(self) -> int | None:
        return self._fixed

    def for_label(self, label: ImportedLabel) -> int:
        if self._fixed is not None:
            return self._fixed
        if label.sequence:
            if label.sequence not in self._by_name:
                self._by_name[label.sequence] = self._named(label.sequence, label.process)
            return self._by_name[label.sequence]
        if self._default is None:
            self._default = self._new_run()
        return self._default

    def _new_run(self) -> int:
        """A new run named after the import (``name (2)``… when taken, also meanwhile)."""
        for _ in range(5):
            name = sequences.unique_sequence_name(self._session, self._name)
            try:
                return sequences.create_sequence(self._session, {"name": name}, self._user).id
            except ConflictError:  # another import took the name meanwhile
                self._session.rollback()
        raise ConflictError("Other imports kept taking the new run's name; import again.")

    def _named(self, name: str, process: dict[str, Any] | None) -> int:
        name = name[:RUN_NAME]
        found = self._session.scalar(sa.select(Sequence).where(Sequence.name == name))
        if found is not None:
            return found.id
        values: dict[str, Any] = {"name": name}
        parameters = {k: v for k, v in (process or {}).items() if k != "name"}
        try:
            values = SequenceIn.model_validate(values | parameters).model_dump(exclude_unset=True)
        except ValidationError:
            self._refused.append(
                Refusal(name, "Its process parameters are not valid; the run is made without.")
            )
        try:
            return sequences.create_sequence(self._session, values, self._user).id
        except ConflictError:  # made meanwhile by another import
            self._session.rollback()
            return self._session.scalars(sa.select(Sequence.id).where(Sequence.name == name)).one()
