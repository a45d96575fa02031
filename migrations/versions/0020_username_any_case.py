"""A user name is one user in any case: a unique index on ``lower(username)``.

Revision ID: 0020
Revises: 0019
Create Date: 2026-12-06 06:00:00.000000

A database that already holds two names differing only by case (made before this revision)
keeps both users and gets no index: the migration warns and goes on, each of the two logs in by
its exact name, and the service refuses a new name that matches another in any case.
"""

from __future__ import annotations

import logging

import sqlalchemy as sa
from alembic import op

revision = '0020'
down_revision = '0019'
branch_labels = None
depends_on = None

INDEX = 'uq_users_lower_username'


def upgrade() -> None:
    twins = op.get_bind().execute(
        sa.text(
            'SELECT lower(username) FROM users GROUP BY lower(username) HAVING count(*) > 1'
        )
    ).scalars().all()
    if twins:
        logging.getLogger('alembic.runtime.migration').warning(
            'User names %s are held by several users differing only by case; the index that '
            'keeps names unique in any case is not made (new names are still refused).',
            ', '.join(repr(name) for name in twins),
        )
        return
    op.create_index(INDEX, 'users', [sa.text('lower(username)')], unique=True)


def downgrade() -> None:
    op.execute(f'DROP INDEX IF EXISTS {INDEX}')
