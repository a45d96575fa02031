"""A label's region outlines as the YOLO export writes them, stored when it is saved.

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-29 20:00:00.000000

Labels saved before this revision keep NULL; the export traces their masks as it goes.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0011'
down_revision = '0010'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('labels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('mask_outlines', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('labels', schema=None) as batch_op:
        batch_op.drop_column('mask_outlines')
