"""What a label holds, one row per fact the frames list filters on (``app.labelconfig.facets``
writes them with the label, in its transaction): a class present (the pool: a mask), a frame
tag, a frame attribute's value. Rows go with their frame (a label is never deleted alone)."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column

from app.core.db import Base


class LabelFacet(Base):
    """``kind`` ``class`` (``key`` its name, ``count`` its objects), ``tag`` (``key`` the tag)
    or ``attr`` (``key`` the frame attribute, ``value`` its value as text)."""

    __tablename__ = "label_facets"
    __table_args__ = (
        # the filter's lookup: every frame with that class, tag or value, from the index alone
        sa.Index("ix_label_facets_lookup", "kind", "key", "value", "frame_id"),
    )

    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"),
        primary_key=True,
        autoincrement=False,
    )
    kind: Mapped[str] = mapped_column(sa.String(8), primary_key=True)
    key: Mapped[str] = mapped_column(sa.String(64), primary_key=True)
    value: Mapped[str] = mapped_column(sa.String(200), default="")
    count: Mapped[int] = mapped_column(default=1)
