"""Frames handed to a person: ``frames.assignee_id`` (SET NULL when the user goes) and when.

Revision ID: 0014
Revises: 0013
Create Date: 2026-12-03 13:40:00.000000

SQLite adds a foreign key by copying the table, which drops the queue's expression indexes
(its reflection cannot read them): they are made again after the copy.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0014'
down_revision = '0013'
branch_labels = None
depends_on = None

UNREVIEWED = sa.text("status IN ('new', 'proposed')")
QUEUE_INDEXES = {
    'ix_frames_queue_sequence': ['sequence_id', sa.text('coalesce(uncertainty, -1.0) DESC'), 'id'],
    'ix_frames_queue': [sa.text('coalesce(uncertainty, -1.0) DESC'), 'id'],
}


def _copying_frames() -> bool:
    return op.get_bind().dialect.name == 'sqlite'


def _drop_queue_indexes() -> None:
    if _copying_frames():
        for name in QUEUE_INDEXES:
            op.drop_index(name, table_name='frames')


def _make_queue_indexes() -> None:
    if _copying_frames():
        for name, columns in QUEUE_INDEXES.items():
            op.create_index(
                name, 'frames', columns, sqlite_where=UNREVIEWED, postgresql_where=UNREVIEWED
            )


def upgrade() -> None:
    _drop_queue_indexes()
    with op.batch_alter_table('frames', schema=None) as batch_op:
        batch_op.add_column(sa.Column('assignee_id', sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column('assigned_at', sa.DateTime(), nullable=True))
        batch_op.create_index(batch_op.f('ix_frames_assignee_id'), ['assignee_id'], unique=False)
        batch_op.create_foreign_key(
            batch_op.f('fk_frames_assignee_id_users'),
            'users',
            ['assignee_id'],
            ['id'],
            ondelete='SET NULL',
        )
    _make_queue_indexes()


def downgrade() -> None:
    _drop_queue_indexes()
    with op.batch_alter_table('frames', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('fk_frames_assignee_id_users'), type_='foreignkey')
        batch_op.drop_index(batch_op.f('ix_frames_assignee_id'))
        batch_op.drop_column('assigned_at')
        batch_op.drop_column('assignee_id')
    _make_queue_indexes()
