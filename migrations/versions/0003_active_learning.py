"""Active learning: uncertainty components and reason, frame descriptors, one training job.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-21 23:40:00.076296
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op



revision = '0003'
down_revision = '0002'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('frames', schema=None) as batch_op:
        batch_op.add_column(sa.Column('uncertainty_components', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('uncertainty_reason', sa.String(length=32), nullable=True))
        batch_op.add_column(sa.Column('descriptor', sa.JSON(), nullable=True))

    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.create_index('uq_jobs_one_training', ['kind'], unique=True, sqlite_where=sa.text("kind = 'train_student' AND status IN ('queued', 'running')"), postgresql_where=sa.text("kind = 'train_student' AND status IN ('queued', 'running')"))



def downgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_index('uq_jobs_one_training', sqlite_where=sa.text("kind = 'train_student' AND status IN ('queued', 'running')"), postgresql_where=sa.text("kind = 'train_student' AND status IN ('queued', 'running')"))

    with op.batch_alter_table('frames', schema=None) as batch_op:
        batch_op.drop_column('descriptor')
        batch_op.drop_column('uncertainty_reason')
        batch_op.drop_column('uncertainty_components')

