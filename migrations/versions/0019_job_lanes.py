"""Lanes, delivery and fan-out: a job's priority within its lane and when the queue last
carried it; a worker's lanes and the job kinds it cannot run; the chunks of a job that several
workers share (``job_chunks``).

Revision ID: 0019
Revises: 0018
Create Date: 2026-12-06 06:00:00.000000

Existing jobs get priority 0 and no delivery time (a queued one is sent again by the next
delivery pass); existing workers serve both lanes and can run every kind until they beat again.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0019'
down_revision = '0018'
branch_labels = None
depends_on = None


def upgrade() -> None:
    # ADD COLUMN in place on both backends: a batch copy of the table would drop SQLite's
    # AUTOINCREMENT (0018).
    op.add_column(
        'jobs', sa.Column('priority', sa.Integer(), nullable=False, server_default=sa.text('0'))
    )
    op.add_column('jobs', sa.Column('enqueued_at', sa.DateTime(), nullable=True))
    op.add_column(
        'workers', sa.Column('lanes', sa.String(32), nullable=False, server_default='quick,model')
    )
    op.add_column('workers', sa.Column('unable', sa.JSON(), nullable=True))
    op.create_table(
        'job_chunks',
        sa.Column('job_id', sa.Integer(), nullable=False),
        sa.Column('chunk', sa.Integer(), nullable=False),
        sa.Column('items', sa.JSON(), nullable=False),
        sa.Column('worker_id', sa.String(200), nullable=True),
        sa.Column('done', sa.Boolean(), nullable=False),
        sa.Column('result', sa.JSON(), nullable=True),
        sa.ForeignKeyConstraint(
            ['job_id'], ['jobs.id'], name='fk_job_chunks_job_id_jobs', ondelete='CASCADE'
        ),
        sa.PrimaryKeyConstraint('job_id', 'chunk', name='pk_job_chunks'),
    )


def downgrade() -> None:  # DROP COLUMN in place: SQLite 3.35 or newer
    op.drop_table('job_chunks')
    for table, column in (
        ('workers', 'unable'),
        ('workers', 'lanes'),
        ('jobs', 'enqueued_at'),
        ('jobs', 'priority'),
    ):
        op.execute(f'ALTER TABLE {table} DROP COLUMN {column}')
