"""A label's mask in COCO's terms (compressed RLE, area, box), stored when it is saved.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-28 18:00:00.000000

Labels saved before this revision keep NULLs; the export encodes their masks as it goes.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0008'
down_revision = '0007'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('labels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('mask_rle', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('mask_area', sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column('mask_bbox', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('labels', schema=None) as batch_op:
        batch_op.drop_column('mask_bbox')
        batch_op.drop_column('mask_area')
        batch_op.drop_column('mask_rle')
