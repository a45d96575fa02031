"""Agreement: a frame given to several annotators keeps each one's label apart
(``overlap_labels``) until a reviewer approves one or merges them.

Revision ID: 0022
Revises: 0021
Create Date: 2026-12-06 08:40:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0022'
down_revision = '0021'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'overlap_labels',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('frame_id', sa.Integer(), nullable=False),
        sa.Column('user_id', sa.Integer(), nullable=False),
        sa.Column('mask_path', sa.String(500), nullable=True),
        sa.Column('keypoints', sa.JSON(), nullable=True),
        sa.Column('created_at', sa.DateTime(), nullable=False),
        sa.Column('updated_at', sa.DateTime(), nullable=True),
        sa.ForeignKeyConstraint(
            ['frame_id'], ['frames.id'], name='fk_overlap_labels_frame_id_frames', ondelete='CASCADE'
        ),
        sa.ForeignKeyConstraint(
            ['user_id'], ['users.id'], name='fk_overlap_labels_user_id_users', ondelete='CASCADE'
        ),
        sa.PrimaryKeyConstraint('id', name='pk_overlap_labels'),
        sa.UniqueConstraint('frame_id', 'user_id', name='uq_overlap_labels_frame_id'),
        sqlite_autoincrement=True,
    )
    op.create_index('ix_overlap_labels_frame_id', 'overlap_labels', ['frame_id'])
    op.create_index('ix_overlap_labels_user_id', 'overlap_labels', ['user_id'])


def downgrade() -> None:
    op.drop_table('overlap_labels')
