"""Indexes that match the frame lists' orders: a run's frames by id, and the review queue.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-28 04:20:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0007'
down_revision = '0006'
branch_labels = None
depends_on = None

UNREVIEWED = sa.text("status IN ('new', 'proposed')")


def upgrade() -> None:
    # The frame-index order breaks ties by id: the index holds the tie-breaker too.
    op.drop_index('ix_frames_sequence_index', table_name='frames')
    op.create_index('ix_frames_sequence_index', 'frames', ['sequence_id', 'frame_index', 'id'])
    op.create_index('ix_frames_sequence_id', 'frames', ['sequence_id', 'id'])
    op.create_index(
        'ix_frames_queue_sequence',
        'frames',
        ['sequence_id', sa.text('coalesce(uncertainty, -1.0) DESC'), 'id'],
        sqlite_where=UNREVIEWED,
        postgresql_where=UNREVIEWED,
    )
    op.create_index(
        'ix_frames_queue',
        'frames',
        [sa.text('coalesce(uncertainty, -1.0) DESC'), 'id'],
        sqlite_where=UNREVIEWED,
        postgresql_where=UNREVIEWED,
    )


def downgrade() -> None:
    op.drop_index('ix_frames_queue', table_name='frames')
    op.drop_index('ix_frames_queue_sequence', table_name='frames')
    op.drop_index('ix_frames_sequence_id', table_name='frames')
    op.drop_index('ix_frames_sequence_index', table_name='frames')
    op.create_index('ix_frames_sequence_index', 'frames', ['sequence_id', 'frame_index'])
