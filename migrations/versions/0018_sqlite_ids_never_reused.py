"""Ids are never reused on SQLite: every table with an integer id gets ``AUTOINCREMENT``.

Revision ID: 0018
Revises: 0017
Create Date: 2026-12-06 05:30:00.000000

Without it SQLite hands the highest id out again after that row is deleted: a review tab still
open on a deleted frame saved its label onto the next upload, and a deleted newest run's id went
to the next run. PostgreSQL's sequences never reuse an id, so nothing changes there.

SQLite sets ``AUTOINCREMENT`` only when a table is made, so each table is rebuilt as SQLite's
"other kinds of table schema changes" procedure says: foreign keys off (a DROP TABLE with them
on would cascade into the rows that point at it), then in one transaction the new table made
from the stored definition, the rows copied, the old table dropped, the new one renamed and every
index (partial and expression indexes too) made again from its stored SQL; a foreign key check
before the commit. The counter starts at each table's highest id.
"""

from __future__ import annotations

import re

from alembic import op

revision = '0018'
down_revision = '0017'
branch_labels = None
depends_on = None

TABLES = (
    'users',
    'api_tokens',
    'web_sessions',
    'sequences',
    'videos',
    'frames',
    'proposals',
    'labels',
    'label_revisions',
    'validation_keypoints',
    'jobs',
    'model_versions',
)
_ID = re.compile(r'(\(\s*)id INTEGER NOT NULL(?=\s*,)')
_AUTO_ID = re.compile(r'(\(\s*)id INTEGER NOT NULL PRIMARY KEY AUTOINCREMENT(?=\s*,)')


def _with_autoincrement(table: str, sql: str) -> str:
    named = re.compile(rf',\s*CONSTRAINT pk_{table} PRIMARY KEY \(id\)')
    sql, keys = named.subn('', sql, count=1)
    sql, ids = _ID.subn(r'\1id INTEGER NOT NULL PRIMARY KEY AUTOINCREMENT', sql, count=1)
    if keys != 1 or ids != 1:
        raise RuntimeError(f'{table} is not as migration 0017 left it; it cannot be rebuilt.')
    return sql


def _without_autoincrement(table: str, sql: str) -> str:
    sql, ids = _AUTO_ID.subn(r'\1id INTEGER NOT NULL', sql, count=1)
    if ids != 1:
        raise RuntimeError(f'{table} is not as migration 0018 left it; it cannot be rebuilt.')
    body = sql.rstrip()
    return f'{body[:-1].rstrip()}, \n\tCONSTRAINT pk_{table} PRIMARY KEY (id)\n)'


def _rebuild(rewrite) -> None:  # type: ignore[no-untyped-def]
    """Every table of TABLES made again from its definition as ``rewrite`` changes it."""
    context = op.get_context()
    with context.autocommit_block():  # PRAGMA foreign_keys is a no-op inside a transaction
        bind = op.get_bind()
        bind.exec_driver_sql('PRAGMA foreign_keys=OFF')
        try:
            bind.exec_driver_sql('BEGIN IMMEDIATE')
            try:
                for table in TABLES:
                    _rebuild_table(bind, table, rewrite)
                broken = bind.exec_driver_sql('PRAGMA foreign_key_check').first()
                if broken is not None:
                    raise RuntimeError(f'A row of {broken[0]} points at a missing row after the rebuild.')
            except BaseException:
                bind.exec_driver_sql('ROLLBACK')
                raise
            bind.exec_driver_sql('COMMIT')
        finally:
            bind.exec_driver_sql('PRAGMA foreign_keys=ON')


def _rebuild_table(bind, table: str, rewrite) -> None:  # type: ignore[no-untyped-def]
    definition = bind.exec_driver_sql(
        "SELECT sql FROM sqlite_master WHERE type = 'table' AND name = ?", (table,)
    ).scalar_one()
    extras = bind.exec_driver_sql(  # indexes and triggers: dropped with the table
        "SELECT sql FROM sqlite_master WHERE tbl_name = ? AND type IN ('index', 'trigger') "
        'AND sql IS NOT NULL ORDER BY rowid',
        (table,),
    ).scalars().all()
    new = f'_rebuilt_{table}'
    created = re.sub(rf'^CREATE TABLE "?{table}"? \(', f'CREATE TABLE {new} (', rewrite(table, definition).lstrip())
    bind.exec_driver_sql(created)
    bind.exec_driver_sql(f'INSERT INTO {new} SELECT * FROM {table}')
    bind.exec_driver_sql(f'DROP TABLE {table}')
    bind.exec_driver_sql(f'ALTER TABLE {new} RENAME TO {table}')
    for sql in extras:
        bind.exec_driver_sql(sql)


def upgrade() -> None:
    if op.get_bind().dialect.name == 'sqlite':
        _rebuild(_with_autoincrement)


def downgrade() -> None:
    if op.get_bind().dialect.name == 'sqlite':
        _rebuild(_without_autoincrement)
