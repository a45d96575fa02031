"""An annotator's own label of a frame given to several keeps the other classes' objects and
the frame's tags and attributes (``overlap_labels.objects``, ``overlap_labels.frame_tags``), as
the frame's label does since 0025.

Revision ID: 0029
Revises: 0028
Create Date: 2026-12-06 18:40:00.000000

Existing rows get NULL: the pool alone, as they were saved.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0029"
down_revision = "0028"
branch_labels = None
depends_on = None

COLUMNS = ("objects", "frame_tags")


def upgrade() -> None:
    # ADD COLUMN in place on both backends: a batch copy of the table would drop SQLite's
    # AUTOINCREMENT (0018).
    for column in COLUMNS:
        op.add_column("overlap_labels", sa.Column(column, sa.JSON(), nullable=True))


def downgrade() -> None:  # DROP COLUMN in place: SQLite 3.35 or newer
    for column in reversed(COLUMNS):
        op.drop_column("overlap_labels", column)
