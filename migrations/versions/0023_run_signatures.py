"""A weld run's signature, stored for the process map (``run_signatures``), and the frames in
its unstable stretches (``unstable_frames``).

Revision ID: 0023
Revises: 0022
Create Date: 2026-12-06 09:00:00.000000

A new table only; existing runs get their signature when first read (a missing row is computed
like a stale one).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0023'
down_revision = '0022'
branch_labels = None
depends_on = None

FIGURES = (
    'width', 'width_q1', 'width_q3', 'length', 'length_q1', 'length_q3',
    'area', 'area_q1', 'area_q3', 'width_cv', 'oscillation_hz', 'oscillation_strength',
)  # fmt: skip


def upgrade() -> None:
    op.create_table(
        'run_signatures',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('sequence_id', sa.Integer(), nullable=False),
        sa.Column('stale', sa.Boolean(), nullable=False),
        sa.Column('policy_source', sa.String(300), nullable=False),
        sa.Column('unit', sa.String(8), nullable=False),
        sa.Column('frames', sa.Integer(), nullable=False),
        sa.Column('measured', sa.Integer(), nullable=False),
        *(sa.Column(name, sa.Float(), nullable=True) for name in FIGURES),
        sa.Column('unstable_frames', sa.Integer(), nullable=False),
        sa.Column('first_unstable_frame_id', sa.Integer(), nullable=True),
        sa.Column('detail', sa.JSON(), nullable=False),
        sa.Column('computed_at', sa.DateTime(), nullable=False),
        sa.ForeignKeyConstraint(
            ['sequence_id'],
            ['sequences.id'],
            name=op.f('fk_run_signatures_sequence_id_sequences'),
            ondelete='CASCADE',
        ),
        sa.PrimaryKeyConstraint('id', name=op.f('pk_run_signatures')),
        sa.UniqueConstraint('sequence_id', name=op.f('uq_run_signatures_sequence_id')),
        sqlite_autoincrement=True,
    )
    op.create_table(
        'unstable_frames',
        sa.Column('frame_id', sa.Integer(), autoincrement=False, nullable=False),
        sa.Column('sequence_id', sa.Integer(), nullable=False),
        sa.Column('rolling_cv', sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(
            ['frame_id'],
            ['frames.id'],
            name=op.f('fk_unstable_frames_frame_id_frames'),
            ondelete='CASCADE',
        ),
        sa.ForeignKeyConstraint(
            ['sequence_id'],
            ['sequences.id'],
            name=op.f('fk_unstable_frames_sequence_id_sequences'),
            ondelete='CASCADE',
        ),
        sa.PrimaryKeyConstraint('frame_id', name=op.f('pk_unstable_frames')),
    )
    op.create_index(
        op.f('ix_unstable_frames_sequence_id'), 'unstable_frames', ['sequence_id'], unique=False
    )


def downgrade() -> None:
    op.drop_table('unstable_frames')
    op.drop_table('run_signatures')
