"""What each label holds, one row per fact the frames list filters on (``label_facets``): the
classes it holds (the pool where it has a mask), its frame tags, its frame attributes' values.

Revision ID: 0028
Revises: 0026
Create Date: 2026-12-06 15:00:00.000000

Existing labels get their rows here, from the columns they hold (as
``app.labelconfig.facets.label_facets`` makes them on every save since).
"""

from __future__ import annotations

import json
import math
from collections import Counter
from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0028"
down_revision = "0026"
branch_labels = None
depends_on = None


def _text(value: Any) -> str | None:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        number = float(value)
        if not math.isfinite(number):
            return None
        return str(int(number)) if number.is_integer() and abs(number) < 1e15 else repr(number)
    return value if isinstance(value, str) and len(value) <= 200 else None


def _json(value: Any) -> Any:
    return json.loads(value) if isinstance(value, str) else value


def _facets(frame_id: int, mask_path: Any, objects: Any, frame_tags: Any) -> list[dict[str, Any]]:
    rows = [(("class", "pool", ""), 1)] if mask_path else []
    held = Counter(
        str(o.get("class"))[:64]
        for o in _json(objects) or []
        if isinstance(o, dict) and o.get("class") not in (None, "pool")
    )
    rows += [(("class", name, ""), n) for name, n in sorted(held.items())]
    frame = _json(frame_tags) or {}
    rows += [(("tag", str(tag)[:64], ""), 1) for tag in sorted(set(frame.get("tags") or []))]
    for name, value in sorted((frame.get("attributes") or {}).items()):
        if (text := _text(value)) is not None:
            rows.append((("attr", str(name)[:64], text), 1))
    return [
        {"frame_id": frame_id, "kind": k, "key": key, "value": v, "count": n}
        for (k, key, v), n in rows
    ]


def upgrade() -> None:
    table = op.create_table(
        "label_facets",
        sa.Column("frame_id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("kind", sa.String(8), nullable=False),
        sa.Column("key", sa.String(64), nullable=False),
        sa.Column("value", sa.String(200), nullable=False),
        sa.Column("count", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["frame_id"],
            ["frames.id"],
            name="fk_label_facets_frame_id_frames",
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("frame_id", "kind", "key", name="pk_label_facets"),
    )
    op.create_index(
        "ix_label_facets_lookup", "label_facets", ["kind", "key", "value", "frame_id"]
    )
    connection = op.get_bind()
    labels = connection.execute(
        sa.text("SELECT frame_id, mask_path, objects, frame_tags FROM labels ORDER BY frame_id")
    )
    while chunk := labels.fetchmany(5000):
        rows = [row for label in chunk for row in _facets(*label)]
        if rows:
            op.bulk_insert(table, rows)


def downgrade() -> None:
    op.drop_index("ix_label_facets_lookup", table_name="label_facets")
    op.drop_table("label_facets")
