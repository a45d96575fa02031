"""The database's schema brought to a revision: alembic's migrations, or on an empty database
the models' schema at once (``app.core.db`` holds the engine and the revision checks; this
module sits above ``app.core.models``, whose tables it makes)."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.engine import Engine
from sqlalchemy.util import OrderedSet

from app.core import models  # noqa: F401  (registers every table on Base.metadata)
from app.core.db import Base, alembic_config, current_revision, head_revision

# A table keeps its indexes in a set, whose order changes from one process to the next, and
# ``create_all`` makes them in that order; SQLite breaks ties between equally costed indexes by
# their order in ``sqlite_master``. Every new home gets them in one order, by name (the list
# queries that matter name their index on SQLite besides: ``app.frames.listing``).
for _table in Base.metadata.tables.values():
    _table.indexes = OrderedSet(sorted(_table.indexes, key=lambda index: str(index.name)))


def migrate(engine: Engine, revision: str = "head") -> None:
    """Bring the schema to ``revision`` (default: the newest); nothing to do costs one query,
    and an empty database gets the newest schema at once (``_create_newest``)."""
    if revision == "head":
        current = current_revision(engine)
        if current == head_revision() or (current is None and _create_newest(engine)):
            return
    from alembic import command

    command.upgrade(alembic_config(engine), revision)


def _create_newest(engine: Engine) -> bool:
    """On a database without any of our tables: the models' schema made in one transaction (a
    failure leaves the database empty) and stamped with the head revision, the schema alembic's
    upgrade from nothing leaves (``tests/test_migrations.py`` holds the two equal); False, and
    nothing done, where any of our tables or alembic's version table is there. A first start
    then neither imports alembic nor runs every migration in turn: 0.2 s of Python beside the
    serving thread's imports."""
    ours = set(Base.metadata.tables) | {"alembic_version"}
    if ours & set(sa.inspect(engine).get_table_names()):
        return False
    version = sa.Table(  # alembic's own version table
        "alembic_version",
        sa.MetaData(),
        sa.Column("version_num", sa.String(32), nullable=False),
        sa.PrimaryKeyConstraint("version_num", name="alembic_version_pkc"),
    )
    with engine.begin() as connection:
        if engine.dialect.name == "sqlite":  # its driver opens no transaction before DDL
            connection.exec_driver_sql("BEGIN")
        Base.metadata.create_all(connection)
        version.create(connection)
        connection.execute(version.insert().values(version_num=head_revision()))
    return True
