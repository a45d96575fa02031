"""Indexes that serve the uncertainty order without a status filter: a run's frames and all
frames, most uncertain first (the home page's default list), read in order instead of sorted.

Revision ID: 0021
Revises: 0020
Create Date: 2026-12-06 08:30:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0021"
down_revision = "0020"
branch_labels = None
depends_on = None

SCORE = sa.text("coalesce(uncertainty, -1.0) DESC")


def upgrade() -> None:
    op.create_index("ix_frames_sequence_uncertainty", "frames", ["sequence_id", SCORE, "id"])
    op.create_index("ix_frames_uncertainty_order", "frames", [SCORE, "id"])


def downgrade() -> None:
    op.drop_index("ix_frames_uncertainty_order", table_name="frames")
    op.drop_index("ix_frames_sequence_uncertainty", table_name="frames")
