"""Frames' DINO descriptors as float32 bytes (``frames.descriptor_f32``) instead of JSON.

Revision ID: 0016
Revises: 0015
Create Date: 2026-12-03 18:00:00.000000

The review queue's first page reads the descriptors of its 50 head frames for the diversity
pick; parsing 50 × 384 floats of JSON was most of that page's time. Existing descriptors are
converted in batches; ``ALTER TABLE … DROP COLUMN`` (SQLite ≥ 3.35, PostgreSQL) removes the old
column without copying the table, so the queue's expression indexes stay.
"""

from __future__ import annotations

import json
import sqlite3
from array import array

import sqlalchemy as sa
from alembic import op

revision = '0016'
down_revision = '0015'
branch_labels = None
depends_on = None

BATCH = 1000


def _float32(values: list[float]) -> bytes:
    packed = array('f', values)
    if packed.itemsize != 4:  # pragma: no cover - every platform weldpool runs on
        raise RuntimeError('float32 is not 4 bytes here')
    if array('H', [1]).tobytes() != b'\x01\x00':  # pragma: no cover - big-endian host
        packed.byteswap()
    return packed.tobytes()


def _convert(source: str, target: str, encode) -> None:  # type: ignore[no-untyped-def]
    bind = op.get_bind()
    frames = sa.table('frames', sa.column('id', sa.Integer), sa.column(source), sa.column(target))
    last = 0
    while True:
        rows = bind.execute(
            sa.select(frames.c.id, frames.c[source])
            .where(frames.c.id > last, frames.c[source].is_not(None))
            .order_by(frames.c.id)
            .limit(BATCH)
        ).all()
        if not rows:
            return
        bind.execute(
            frames.update().where(frames.c.id == sa.bindparam('frame_id')),
            [{'frame_id': row[0], target: encode(row[1])} for row in rows],
        )
        last = rows[-1][0]


UNREVIEWED = sa.text("status IN ('new', 'proposed')")
QUEUE_INDEXES = {  # as 0014 made them
    'ix_frames_queue_sequence': ['sequence_id', sa.text('coalesce(uncertainty, -1.0) DESC'), 'id'],
    'ix_frames_queue': [sa.text('coalesce(uncertainty, -1.0) DESC'), 'id'],
}


def _drop_column(name: str) -> None:
    """In place where the database can (PostgreSQL, SQLite ≥ 3.35); an older SQLite copies
    the table, which loses the queue's expression indexes: they are made again."""
    bind = op.get_bind()
    if bind.dialect.name != 'sqlite' or sqlite3.sqlite_version_info >= (3, 35):
        op.execute(f'ALTER TABLE frames DROP COLUMN {name}')
        return
    for index in QUEUE_INDEXES:
        op.drop_index(index, table_name='frames')
    with op.batch_alter_table('frames') as batch_op:
        batch_op.drop_column(name)
    for index, columns in QUEUE_INDEXES.items():
        op.create_index(index, 'frames', columns, sqlite_where=UNREVIEWED, postgresql_where=UNREVIEWED)


def upgrade() -> None:
    op.add_column('frames', sa.Column('descriptor_f32', sa.LargeBinary(), nullable=True))

    def encode(value):  # type: ignore[no-untyped-def]
        values = json.loads(value) if isinstance(value, str) else value
        return _float32([float(v) for v in values]) if values else None  # JSON null, []

    _convert('descriptor', 'descriptor_f32', encode)
    _drop_column('descriptor')


def downgrade() -> None:
    op.add_column('frames', sa.Column('descriptor', sa.JSON(), nullable=True))

    def decode(value):  # type: ignore[no-untyped-def]
        packed = array('f')
        packed.frombytes(bytes(value))
        if array('H', [1]).tobytes() != b'\x01\x00':  # pragma: no cover
            packed.byteswap()
        return json.dumps([round(v, 5) for v in packed])

    _convert('descriptor_f32', 'descriptor', decode)
    _drop_column('descriptor_f32')
