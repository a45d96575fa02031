"""Where a label came from when it was not drawn here: ``{"kind": "imported", "format", "file"}``.

Revision ID: 0012
Revises: 0011
Create Date: 2026-12-02 19:30:00.000000

Labels and revisions made in the review keep NULL.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0012'
down_revision = '0011'
branch_labels = None
depends_on = None


def upgrade() -> None:
    for table in ('labels', 'label_revisions'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column('source', sa.JSON(), nullable=True))


def downgrade() -> None:
    for table in ('labels', 'label_revisions'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column('source')
