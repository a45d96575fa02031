"""A revision on validation keypoints (``validation_keypoints.revision``), so a save made from
keypoints someone else has replaced meanwhile is a 409, as a label's is.

Revision ID: 0017
Revises: 0016
Create Date: 2026-12-06 00:10:00.000000

Existing rows start at revision 1.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0017'
down_revision = '0016'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('validation_keypoints', schema=None) as batch_op:
        batch_op.add_column(
            sa.Column('revision', sa.Integer(), nullable=False, server_default=sa.text('1'))
        )


def downgrade() -> None:
    with op.batch_alter_table('validation_keypoints', schema=None) as batch_op:
        batch_op.drop_column('revision')
