"""A student version's int8 student: how its masks agreed with the float student's and how much
faster it ran (null: none); at most one quantizing job queued or running, as for training.

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-29 17:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0010'
down_revision = '0009'
branch_labels = None
depends_on = None

OLD = "kind IN ('train_student', 'train_sequential') AND status IN ('queued', 'running')"
NEW = (
    "kind IN ('train_student', 'train_sequential', 'quantize_student') "
    "AND status IN ('queued', 'running')"
)


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
        batch_op.add_column(sa.Column('int8', sa.JSON(), nullable=True))
    _one_at_a_time(NEW)


def downgrade() -> None:
    _one_at_a_time(OLD)
    with op.batch_alter_table('model_versions', schema=None) as batch_op:
        batch_op.drop_column('int8')
