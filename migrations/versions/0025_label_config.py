"""The instance's label configuration, one row per version (``label_configs``), and the other
classes' objects and the frame's tags beside the pool on each label and revision.

Revision ID: 0025
Revises: 0024
Create Date: 2026-12-06 09:30:00.000000

Existing labels are the pool's: their new columns are NULL and nothing they hold changes; an
instance without a configuration row has the pool alone (version 0).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0025"
down_revision = "0024"
branch_labels = None
depends_on = None

COLUMNS = (
    ("labels", "objects"),
    ("labels", "frame_tags"),
    ("label_revisions", "objects"),
    ("label_revisions", "frame_tags"),
)


def upgrade() -> None:
    # ADD COLUMN in place on both backends: a batch copy of the table would drop SQLite's
    # AUTOINCREMENT (0018).
    for table, column in COLUMNS:
        op.add_column(table, sa.Column(column, sa.JSON(), nullable=True))
    op.create_table(
        "label_configs",
        sa.Column("version", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("config", sa.JSON(), nullable=False),
        sa.Column("user_id", sa.Integer(), nullable=True),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_id"], ["users.id"], name="fk_label_configs_user_id_users", ondelete="SET NULL"
        ),
        sa.PrimaryKeyConstraint("version", name="pk_label_configs"),
    )


def downgrade() -> None:  # DROP COLUMN in place: SQLite 3.35 or newer
    op.drop_table("label_configs")
    for table, column in reversed(COLUMNS):
        op.execute(f"ALTER TABLE {table} DROP COLUMN {column}")
