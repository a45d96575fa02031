"""The display policy stored as a row (``display_policies``), measured when what changes it is
committed instead of on each read.

Revision ID: 0026
Revises: 0025
Create Date: 2026-12-06 12:00:00.000000

A new table with its one row, stale: the first read or write measures it.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0026'
down_revision = '0025'
branch_labels = None
depends_on = None


def upgrade() -> None:
    table = op.create_table(
        'display_policies',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('stale', sa.Boolean(), nullable=False),
        sa.Column('chosen', sa.String(300), nullable=False),
        sa.Column('reason', sa.Text(), nullable=False),
        sa.Column('sources', sa.JSON(), nullable=False),
        sa.Column('measured_at', sa.DateTime(), nullable=True),
        sa.PrimaryKeyConstraint('id', name=op.f('pk_display_policies')),
        sqlite_autoincrement=True,
    )
    op.bulk_insert(
        table, [{'id': 1, 'stale': True, 'chosen': 'teacher', 'reason': '', 'sources': []}]
    )


def downgrade() -> None:
    op.drop_table('display_policies')
