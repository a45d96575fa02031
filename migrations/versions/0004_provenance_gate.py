"""Proposals with provenance and a promotion gate: what a label started from, what a student
version trained on and held out, and the gate's verdict.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-27 17:50:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0004'
down_revision = '0003'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('labels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('mask_changed', sa.Boolean(), nullable=True))
    with op.batch_alter_table('label_revisions', schema=None) as batch_op:
        batch_op.add_column(sa.Column('mask_changed', sa.Boolean(), nullable=True))
    with op.batch_alter_table('model_versions', schema=None) as batch_op:
        batch_op.add_column(sa.Column('train_frame_ids', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('held_out_frame_ids', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('gate', sa.JSON(), nullable=True))
    with op.batch_alter_table('proposals', schema=None) as batch_op:
        batch_op.create_index('ix_proposals_frame_source', ['frame_id', 'source'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('proposals', schema=None) as batch_op:
        batch_op.drop_index('ix_proposals_frame_source')
    with op.batch_alter_table('model_versions', schema=None) as batch_op:
        batch_op.drop_column('gate')
        batch_op.drop_column('held_out_frame_ids')
        batch_op.drop_column('train_frame_ids')
    with op.batch_alter_table('label_revisions', schema=None) as batch_op:
        batch_op.drop_column('mask_changed')
    with op.batch_alter_table('labels', schema=None) as batch_op:
        batch_op.drop_column('mask_changed')
