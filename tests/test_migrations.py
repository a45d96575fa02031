"""Migrations bring an empty database to head on SQLite and PostgreSQL, and match the models."""

from __future__ import annotations

import pytest
import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy.orm import Session

from app.db import MIGRATIONS_DIR, Base, create_db_engine, head_revision, migrate, schema_revision

CORE_TABLES = {
    "users",
    "api_tokens",
    "web_sessions",
    "sequences",
    "frames",
    "proposals",
    "labels",
    "label_revisions",
    "validation_keypoints",
    "jobs",
    "workers",
    "model_versions",
}


def test_upgrade_empty_database_to_head(database_url: str) -> None:
    engine = create_db_engine(database_url)
    assert schema_revision(engine)[0] is None
    migrate(engine)
    current, head = schema_revision(engine)
    assert current == head and head
    assert set(sa.inspect(engine).get_table_names()) >= CORE_TABLES
    migrate(engine)  # idempotent
    engine.dispose()


def test_the_head_read_from_the_files_is_alembics() -> None:
    """The start-up's head (read without importing alembic) is the one alembic computes."""
    from alembic.script import ScriptDirectory

    assert head_revision() == ScriptDirectory(str(MIGRATIONS_DIR)).get_current_head()
    assert head_revision() == max(p.name[:4] for p in (MIGRATIONS_DIR / "versions").glob("0*.py"))


def test_a_current_database_is_not_migrated_again(
    database_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Serving a current database skips alembic; one a revision behind is brought to head."""
    import alembic.command

    engine = create_db_engine(database_url)
    migrate(engine, "0014")
    assert schema_revision(engine)[0] == "0014"
    migrate(engine)
    assert schema_revision(engine)[0] == head_revision()

    def refuse(*args: object) -> None:
        raise AssertionError("a current database was migrated again")

    monkeypatch.setattr(alembic.command, "upgrade", refuse)
    migrate(engine)  # current: no upgrade
    engine.dispose()


def test_migrations_match_the_models(database_url: str) -> None:
    engine = create_db_engine(database_url)
    migrate(engine)
    with engine.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    engine.dispose()
    assert diff == [], f"models and migrations differ; write a migration: {diff}"


def test_downgrade_to_base_and_back(database_url: str) -> None:
    engine = create_db_engine(database_url)
    migrate(engine)
    from alembic import command

    from app.db import _alembic_config

    command.downgrade(_alembic_config(engine), "base")
    assert not CORE_TABLES & set(sa.inspect(engine).get_table_names())
    migrate(engine)
    assert set(sa.inspect(engine).get_table_names()) >= CORE_TABLES
    engine.dispose()


def test_sqlite_runs_in_wal_mode_with_foreign_keys(tmp_path) -> None:
    engine = create_db_engine(f"sqlite:///{tmp_path / 'db.sqlite3'}")
    migrate(engine)
    with engine.connect() as connection:
        assert connection.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
        try:
            connection.exec_driver_sql(
                "INSERT INTO api_tokens (user_id, name, token_hash, prefix, created_at) "
                "VALUES (999, 'x', 'h', 'p', '2026-01-01')"
            )
        except sa.exc.IntegrityError:
            pass
        else:
            raise AssertionError("a token of a missing user was stored: foreign keys are off")
    engine.dispose()


@pytest.mark.parametrize("old_sqlite", [False, True])
def test_descriptors_stored_as_json_become_float32_and_back(
    database_url: str, old_sqlite: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """0016's downgrade writes each frame's float32 descriptor as JSON, and its upgrade turns
    that JSON into float32 bytes again (frames without one stay empty); on a SQLite older than
    3.35 (no DROP COLUMN) the table is copied and the queue's indexes are made again."""
    if old_sqlite:
        if not database_url.startswith("sqlite"):
            return  # PostgreSQL has one way
        import sqlite3

        monkeypatch.setattr(sqlite3, "sqlite_version_info", (3, 31, 1))
    import numpy as np
    from alembic import command

    from app.db import _alembic_config
    from app.models import Frame, Sequence

    engine = create_db_engine(database_url)
    migrate(engine)
    vector = [0.125, -1.5, 3.0e-3, 0.333333]
    with Session(engine) as session:
        run = Sequence(name="r")
        session.add(run)
        session.flush()
        for index, descriptor in enumerate([vector, None]):
            session.add(
                Frame(
                    sequence_id=run.id,
                    sha256=f"{index:064d}",
                    path=f"frames/{index}.png",
                    original_name=f"{index}.png",
                    media_type="image/png",
                    size_bytes=1,
                    width=2,
                    height=2,
                    channels=3,
                    descriptor=descriptor,
                )
            )
        session.commit()
    command.downgrade(_alembic_config(engine), "0015")
    json_column = sa.column("descriptor", sa.JSON())
    with engine.connect() as connection:
        query = sa.text("SELECT descriptor FROM frames ORDER BY id").columns(json_column)
        stored = connection.execute(query).scalars().all()
    assert stored[0] == pytest.approx(vector, abs=1e-5) and stored[1] is None
    migrate(engine)
    with Session(engine) as session:
        frames = session.scalars(sa.select(Frame).order_by(Frame.id)).all()
        assert frames[0].descriptor.dtype == np.float32
        np.testing.assert_allclose(frames[0].descriptor, np.float32(vector), atol=1e-5)
        assert frames[1].descriptor is None
    with engine.connect() as connection:  # (SQLite's reflection skips expression indexes)
        names = connection.execute(
            sa.text("SELECT name FROM sqlite_master WHERE type = 'index'")
            if database_url.startswith("sqlite")
            else sa.text("SELECT indexname FROM pg_indexes WHERE tablename = 'frames'")
        ).scalars()
        assert {"ix_frames_queue", "ix_frames_queue_sequence"} <= set(names)
    engine.dispose()
