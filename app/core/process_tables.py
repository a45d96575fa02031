"""The process map's tables: each weld run's stored signature and the frames inside its
unstable stretches (``app.process``). Imported with every other table from ``app.core.models``,
whose listener marks a signature stale when its run changes."""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column

from app.core.db import Base, JSONType, UTCDateTime, utcnow


class RunSignature(Base):
    """A weld run's signature (``weldpool_core.signature``), stored so the process map reads
    rows instead of masks: the figures the map plots in columns (in ``unit``: mm with the run's
    scale, else px), everything else (trends, stretches with their frames, the rolling CV) in
    ``detail``. ``stale`` is set by ``_signatures_go_stale`` in the transaction that changes the
    run's labels, proposals or frames; the next read computes it again."""

    __tablename__ = "run_signatures"

    id: Mapped[int] = mapped_column(primary_key=True)
    sequence_id: Mapped[int] = mapped_column(
        sa.ForeignKey("sequences.id", ondelete="CASCADE"), unique=True
    )
    stale: Mapped[bool] = mapped_column(default=False)
    policy_source: Mapped[str] = mapped_column(sa.String(300))
    """The proposal source the policy showed when it was computed (a new one: stale)."""
    unit: Mapped[str] = mapped_column(sa.String(8))
    frames: Mapped[int]
    measured: Mapped[int]
    width: Mapped[float | None] = mapped_column(sa.Float)
    width_q1: Mapped[float | None] = mapped_column(sa.Float)
    width_q3: Mapped[float | None] = mapped_column(sa.Float)
    length: Mapped[float | None] = mapped_column(sa.Float)
    length_q1: Mapped[float | None] = mapped_column(sa.Float)
    length_q3: Mapped[float | None] = mapped_column(sa.Float)
    area: Mapped[float | None] = mapped_column(sa.Float)
    area_q1: Mapped[float | None] = mapped_column(sa.Float)
    area_q3: Mapped[float | None] = mapped_column(sa.Float)
    width_cv: Mapped[float | None] = mapped_column(sa.Float)
    oscillation_hz: Mapped[float | None] = mapped_column(sa.Float)
    oscillation_strength: Mapped[float | None] = mapped_column(sa.Float)
    unstable_frames: Mapped[int] = mapped_column(default=0)
    first_unstable_frame_id: Mapped[int | None]
    detail: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    computed_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class UnstableFrame(Base):
    """A frame inside one of its run's unstable stretches (the stored signature's): what the
    frames list filters on and the review queue can favour."""

    __tablename__ = "unstable_frames"

    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), primary_key=True, autoincrement=False
    )
    sequence_id: Mapped[int] = mapped_column(
        sa.ForeignKey("sequences.id", ondelete="CASCADE"), index=True
    )
    rolling_cv: Mapped[float | None] = mapped_column(sa.Float)
