"""A job's listed frames in their own table (``job_scopes``), so its parameters stay small;
the claims of runs proposing a frame (``proposal_claims``), so overlapping runs propose it once;
the files whose rows went (``doomed_files``), so the collector need not list the whole store.

Revision ID: 0024
Revises: 0023
Create Date: 2026-12-06 08:30:00.000000

Jobs queued before keep their ``frame_ids`` parameter, which workers still read.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0024'
down_revision = '0023'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'job_scopes',
        sa.Column('job_id', sa.Integer(), autoincrement=False, nullable=False),
        sa.Column('frame_ids', sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ['job_id'], ['jobs.id'], name='fk_job_scopes_job_id_jobs', ondelete='CASCADE'
        ),
        sa.PrimaryKeyConstraint('job_id', name='pk_job_scopes'),
    )
    op.create_table(
        'proposal_claims',
        sa.Column('frame_id', sa.Integer(), autoincrement=False, nullable=False),
        sa.Column('model_id', sa.String(255), nullable=False),
        sa.Column('job_id', sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ['frame_id'], ['frames.id'], name='fk_proposal_claims_frame_id_frames', ondelete='CASCADE'
        ),
        sa.ForeignKeyConstraint(
            ['job_id'], ['jobs.id'], name='fk_proposal_claims_job_id_jobs', ondelete='CASCADE'
        ),
        sa.PrimaryKeyConstraint('frame_id', 'model_id', name='pk_proposal_claims'),
    )


    op.create_table(
        'doomed_files',
        sa.Column('path', sa.String(500), nullable=False),
        sa.Column('since', sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint('path', name='pk_doomed_files'),
    )


def downgrade() -> None:
    op.drop_table('doomed_files')
    op.drop_table('proposal_claims')
    op.drop_table('job_scopes')
