"""A weld run's image scale (mm per pixel), for geometry in millimetres.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-27 22:10:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0006'
down_revision = '0005'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.add_column(sa.Column('mm_per_px', sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.drop_column('mm_per_px')
