"""The review stage: a label's ``review`` (awaiting, approved, returned) and the reviewer's
``review_comment``, on labels and in their history.

Revision ID: 0015
Revises: 0014
Create Date: 2026-12-03 14:00:00.000000

Existing labels keep NULL: they count as approved.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0015'
down_revision = '0014'
branch_labels = None
depends_on = None

STATES = sa.Enum(
    'awaiting',
    'approved',
    'returned',
    name='review_state',
    native_enum=False,
    length=16,
)


def upgrade() -> None:
    for table in ('labels', 'label_revisions'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column('review', STATES, nullable=True))
            batch_op.add_column(sa.Column('review_comment', sa.String(length=1000), nullable=True))


def downgrade() -> None:
    for table in ('labels', 'label_revisions'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column('review_comment')
            batch_op.drop_column('review')
