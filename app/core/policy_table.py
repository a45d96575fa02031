"""The display policy's stored row (``display_policies``, one row, id 1): which proposal source
reviewers see and every source's score, as ``app.proposals.policy`` measured it. That module's
listeners measure it again before a transaction that changes what it is measured from (a label
or its revision, a proposal, a model version, a bulk frame deletion) commits, or mark it
``stale`` where the session does not know the store; a read then measures it."""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column

from app.core.db import Base, JSONType, UTCDateTime, utcnow

ROW = 1


class DisplayPolicy(Base):
    """The stored policy: ``chosen`` source key, its ``reason``, ``sources`` (each source's
    score as ``SourceScore.as_dict``), and ``stale`` while a committed change waits for it."""

    __tablename__ = "display_policies"

    id: Mapped[int] = mapped_column(primary_key=True)
    stale: Mapped[bool] = mapped_column(default=True)
    chosen: Mapped[str] = mapped_column(sa.String(300), default="teacher")
    reason: Mapped[str] = mapped_column(sa.Text, default="")
    sources: Mapped[list[dict[str, Any]]] = mapped_column(JSONType, default=list)
    measured_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, default=utcnow)


# A new home's database holds the row from the start, so writers only ever update it.
sa.event.listen(
    DisplayPolicy.__table__,
    "after_create",
    sa.DDL(  # type: ignore[no-untyped-call]
        "INSERT INTO display_policies (id, stale, chosen, reason, sources) "
        f"VALUES ({ROW}, true, 'teacher', '', '[]')"
    ),
)
