"""Alembic environment: uses the engine handed over by ``app.core.db.migrate`` or the settings."""

from __future__ import annotations

from alembic import context

from app.core import models  # noqa: F401  (registers every table on Base.metadata)
from app.core.db import Base, create_db_engine

config = context.config
engine = config.attributes.get("engine")
if engine is None:  # run through the `alembic` command line: read the settings
    from app.core.config import get_settings

    engine = create_db_engine(get_settings().resolved_database_url)

with engine.connect() as connection:
    context.configure(
        connection=connection,
        target_metadata=Base.metadata,
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
    )
    with context.begin_transaction():
        context.run_migrations()
    connection.commit()
