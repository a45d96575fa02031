"""A student version's sequential cell: its training record and how it measured against the
per-frame student (null: no cell); at most one sequential-cell job queued or running, as for
training a student.

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-29 13:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0009'
down_revision = '0008'
branch_labels = None
depends_on = None

OLD = "kind = 'train_student' AND status IN ('queued', 'running')"
NEW = "kind IN ('train_student', 'train_sequential') AND status IN ('queued', 'running')"


def _one_at_a_time(where: str) -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_index('uq_jobs_one_training')
        batch_op.create_index(
            'uq_jobs_one_training',
            ['kind'],
            unique=True,
            sqlite_where=sa.text(where),
            postgresql_where=sa.text(where),
        )


def upgrade() -> None:
    with op.batch_alter_table('model_versions', schema=None) as batch_op:
        batch_op.add_column(sa.Column('sequential', sa.JSON(), nullable=True))
    _one_at_a_time(NEW)


def downgrade() -> None:
    _one_at_a_time(OLD)
    with op.batch_alter_table('model_versions', schema=None) as batch_op:
        batch_op.drop_column('sequential')
