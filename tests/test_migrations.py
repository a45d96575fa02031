"""Migrations bring an empty database to head on SQLite and PostgreSQL, and match the models."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy.orm import Session

from app.core.db import MIGRATIONS_DIR, Base, create_db_engine, head_revision, schema_revision
from app.core.schema import migrate
from tests.helpers import postgres_schema

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


def _upgrade_with_alembic(engine: sa.Engine) -> None:
    """The migrations from nothing to head, one by one (``migrate`` makes an empty database's
    schema from the models at once)."""
    from alembic import command

    from app.core.db import alembic_config

    command.upgrade(alembic_config(engine), "head")


def _schema(engine: sa.Engine) -> dict[str, object]:
    """Everything the database says of its tables: columns (type, nullability, default),
    primary and foreign keys, indexes and unique constraints with their names, and the
    version alembic reads."""
    inspector = sa.inspect(engine)
    tables: dict[str, object] = {}
    for table in sorted(inspector.get_table_names()):
        tables[table] = {
            "columns": sorted(  # by name: migrations add columns at the end, the models in place
                (c["name"], str(c["type"]), c["nullable"], c.get("default"))
                for c in inspector.get_columns(table)
            ),
            "primary": inspector.get_pk_constraint(table),
            "foreign": sorted(
                (f["name"] or "", f["constrained_columns"], f["referred_table"], f["options"])
                for f in inspector.get_foreign_keys(table)
            ),
            "indexes": sorted(
                (
                    i["name"] or "",
                    i["column_names"],
                    i["unique"],
                    {k: str(v) for k, v in i.get("dialect_options", {}).items()},  # partial: WHERE
                )
                for i in inspector.get_indexes(table)
            ),
            "unique": sorted(
                (u["name"] or "", u["column_names"])
                for u in inspector.get_unique_constraints(table)
            ),
        }
    with engine.connect() as connection:  # the catalog itself: expression indexes too
        if engine.dialect.name == "sqlite":
            catalog = [  # an index's definition as written, spacing and quotes aside
                (kind, name, table, " ".join((sql or "").replace('"', "").split()))
                if kind == "index"
                else (kind, name, table, "AUTOINCREMENT" in (sql or ""))
                for kind, name, table, sql in connection.exec_driver_sql(
                    "SELECT type, name, tbl_name, sql FROM sqlite_master "
                    "WHERE name NOT LIKE 'sqlite_%'"
                )
            ]
        else:  # PostgreSQL writes each index's definition in one canonical form
            catalog = connection.exec_driver_sql(
                "SELECT indexname, replace(indexdef, current_schema() || '.', '') FROM pg_indexes "
                "WHERE schemaname = current_schema()"
            ).all()
    return {
        "tables": tables,
        "catalog": sorted(tuple(row) for row in catalog),
        "version": schema_revision(engine)[0],
    }


@pytest.fixture
def second_database_url(database_url: str, tmp_path) -> Iterator[str]:
    """Another empty database of the same kind: a SQLite file, or a fresh PostgreSQL schema."""
    if database_url.startswith("sqlite"):
        yield f"sqlite:///{tmp_path / 'second.sqlite3'}"
        return
    with postgres_schema() as url:
        yield url


def test_a_first_start_makes_the_schema_the_migrations_make(
    database_url: str, second_database_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An empty database gets the models' schema at once, without alembic: the same tables,
    columns, keys, indexes, constraint names and version as every migration from nothing."""
    import alembic.command

    def refuse(*args: object) -> None:
        raise AssertionError("an empty database was migrated step by step")

    created, migrated = create_db_engine(database_url), create_db_engine(second_database_url)
    with monkeypatch.context() as patch:
        patch.setattr(alembic.command, "upgrade", refuse)
        migrate(created)
    _upgrade_with_alembic(migrated)
    made, stepped = _schema(created), _schema(migrated)
    created.dispose(), migrated.dispose()
    assert set(made["tables"]) >= CORE_TABLES | {"alembic_version"}  # type: ignore[call-overload]
    assert made["version"] == head_revision()
    assert made == stepped


def test_a_first_start_that_fails_leaves_the_database_empty(
    database_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The schema is made in one transaction (SQLite's driver opens none before DDL by itself):
    a failure after the tables were made leaves none of them, and the next start makes it."""
    made = Base.metadata.create_all

    def fail_after(connection: sa.Connection, **kwargs: object) -> None:
        made(connection, **kwargs)  # type: ignore[arg-type]
        raise RuntimeError("the disk is full")

    engine = create_db_engine(database_url)
    with monkeypatch.context() as patch:
        patch.setattr(Base.metadata, "create_all", fail_after)
        with pytest.raises(RuntimeError, match="disk is full"):
            migrate(engine)
    assert sa.inspect(engine).get_table_names() == []
    migrate(engine)
    assert schema_revision(engine)[0] == head_revision()
    engine.dispose()


def test_a_database_with_some_of_our_tables_is_migrated_step_by_step(database_url: str) -> None:
    """Where any of our tables is there without a version (a half-made database), nothing is
    made from the models: alembic runs, and refuses as it always did."""
    engine = create_db_engine(database_url)
    with engine.begin() as connection:
        connection.exec_driver_sql("CREATE TABLE users (id INTEGER PRIMARY KEY)")
    with pytest.raises(sa.exc.SQLAlchemyError):
        migrate(engine)
    assert schema_revision(engine)[0] is None
    engine.dispose()


def test_migrations_match_the_models(database_url: str) -> None:
    engine = create_db_engine(database_url)
    _upgrade_with_alembic(engine)
    with engine.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    engine.dispose()
    assert diff == [], f"models and migrations differ; write a migration: {diff}"


def test_downgrade_to_base_and_back(database_url: str) -> None:
    engine = create_db_engine(database_url)
    migrate(engine)
    from alembic import command

    from app.core.db import alembic_config

    command.downgrade(alembic_config(engine), "base")
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

    from app.core.db import alembic_config
    from app.core.models import Frame, Sequence

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
    command.downgrade(alembic_config(engine), "0015")
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


def _index_definitions(engine: sa.Engine) -> set[str]:
    """Every index and trigger as the database stores it (SQLite: its SQL; PostgreSQL: its
    canonical definition)."""
    with engine.connect() as connection:
        if engine.dialect.name == "sqlite":
            rows = connection.exec_driver_sql(
                "SELECT sql FROM sqlite_master WHERE type IN ('index', 'trigger') "
                "AND sql IS NOT NULL"
            )
        else:
            rows = connection.exec_driver_sql(
                "SELECT indexdef FROM pg_indexes WHERE schemaname = current_schema()"
            )
        return {" ".join(sql.replace('"', "").split()) for sql in rows.scalars()}


def _fill(engine: sa.Engine) -> dict[str, int]:
    """A user, a run, three frames with a proposal and a label each (revisions too), a job and
    a model version; the row count of each of their tables."""
    from app.core.models import Frame, Label, LabelRevision, LabelStatus, Proposal, Sequence, User

    with Session(engine) as session:
        user = User(username="ada", password_hash="x", role="admin")
        run = Sequence(name="r")
        session.add_all([user, run])
        session.flush()
        for index in range(3):
            frame = Frame(
                sequence_id=run.id,
                sha256=f"{index:064d}",
                path=f"frames/{index}.png",
                original_name=f"{index}.png",
                media_type="image/png",
                size_bytes=1,
                width=2,
                height=2,
                channels=3,
            )
            session.add(frame)
            session.flush()
            proposal = Proposal(frame_id=frame.id, source="teacher", model_id="t", mask_path="m")
            session.add(proposal)
            session.flush()
            session.add(
                Label(
                    frame_id=frame.id,
                    status=LabelStatus.corrected,
                    mask_path=f"labels/{index}.png",
                    proposal_id=proposal.id,
                    updated_by_id=user.id,
                )
            )
            session.add(
                LabelRevision(
                    frame_id=frame.id,
                    revision=1,
                    status=LabelStatus.corrected,
                    mask_path=f"labels/{index}.png",
                    user_id=user.id,
                )
            )
        session.commit()
    with engine.begin() as connection:  # the columns 0017 has (the models' may be more)
        connection.exec_driver_sql(
            "INSERT INTO jobs (kind, status, progress, message, params, attempts, max_attempts, "
            "cancel_requested, created_at) VALUES "
            "('teacher', 'queued', 0, '', '{}', 0, 1, false, '2026-01-01 00:00:00')"
        )
        connection.exec_driver_sql(
            "INSERT INTO model_versions (name, config, metrics, curve, train_label_count, "
            "is_promoted, created_at) VALUES "
            "('v1', '{}', '{}', '[]', 0, false, '2026-01-01 00:00:00')"
        )
    with engine.connect() as connection:
        return {
            table: connection.exec_driver_sql(f"SELECT count(*) FROM {table}").scalar_one()
            for table in (
                "users",
                "sequences",
                "frames",
                "proposals",
                "labels",
                "label_revisions",
                "jobs",
                "model_versions",
            )
        }


def test_ids_are_never_reused_after_0018_on_a_filled_database(database_url: str) -> None:
    """0018 rebuilds SQLite's tables with AUTOINCREMENT keeping every row, reference, index
    (partial and expression ones too) and the foreign keys on; afterwards the id of a deleted
    newest row is given to nobody (SQLite gave it to the next insert; PostgreSQL never did)."""
    from alembic import command

    from app.core.db import alembic_config

    engine = create_db_engine(database_url)
    migrate(engine, "0017")
    counts = _fill(engine)
    indexes = _index_definitions(engine)
    assert any("coalesce" in sql.lower() for sql in indexes)  # the queue's expression indexes
    command.upgrade(alembic_config(engine), "0018")
    with engine.connect() as connection:
        after = {
            table: connection.exec_driver_sql(f"SELECT count(*) FROM {table}").scalar_one()
            for table in counts
        }
        joined = connection.exec_driver_sql(
            "SELECT count(*) FROM labels JOIN frames ON frames.id = labels.frame_id "
            "JOIN proposals ON proposals.id = labels.proposal_id"
        ).scalar_one()
        if engine.dialect.name == "sqlite":
            assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
            assert connection.exec_driver_sql("PRAGMA foreign_key_check").first() is None
    assert after == counts and joined == 3
    assert _index_definitions(engine) == indexes
    with engine.begin() as connection:  # the newest frame deleted (its label goes with it)
        newest = connection.exec_driver_sql("SELECT max(id) FROM frames").scalar_one()
        connection.exec_driver_sql(f"DELETE FROM frames WHERE id = {newest}")
        assert connection.exec_driver_sql("SELECT count(*) FROM labels").scalar_one() == 2
        connection.exec_driver_sql(
            "INSERT INTO frames (sequence_id, sha256, path, original_name, media_type, "
            "size_bytes, width, height, channels, bit_depth, split, status, created_at) "
            "SELECT sequence_id, 'f', path, original_name, media_type, size_bytes, width, "
            "height, channels, bit_depth, split, status, created_at FROM frames LIMIT 1"
        )
        assert connection.exec_driver_sql("SELECT max(id) FROM frames").scalar_one() > newest
    command.downgrade(alembic_config(engine), "0017")  # and back: the rows stay
    with engine.connect() as connection:
        assert connection.exec_driver_sql("SELECT count(*) FROM frames").scalar_one() == 3
    assert _index_definitions(engine) == indexes
    engine.dispose()


def test_0025_leaves_every_label_the_pools_as_it_was(database_url: str) -> None:
    """On a filled database, 0025 adds the label configuration and the objects and tags columns
    in place: every label and revision holds what it held (the pool's), with no objects or
    tags, and the instance has no configuration row (the pool alone); and back."""
    from alembic import command

    from app.core.db import alembic_config

    engine = create_db_engine(database_url)
    migrate(engine, "0024")
    counts = _fill(engine)
    held = "SELECT frame_id, revision, status, mask_path, proposal_id FROM {} ORDER BY frame_id"
    with engine.connect() as connection:
        before = {
            t: connection.exec_driver_sql(held.format(t)).all()
            for t in ("labels", "label_revisions")
        }
    command.upgrade(alembic_config(engine), "0025")
    with engine.connect() as connection:
        after = {t: connection.exec_driver_sql(held.format(t)).all() for t in before}
        new = {
            t: connection.exec_driver_sql(f"SELECT objects, frame_tags FROM {t}").all()
            for t in before
        }
        configs = connection.exec_driver_sql("SELECT count(*) FROM label_configs").scalar_one()
        total = {
            t: connection.exec_driver_sql(f"SELECT count(*) FROM {t}").scalar_one() for t in counts
        }
    assert after == before and len(after["labels"]) == 3 and total == counts
    assert all(row == (None, None) for rows in new.values() for row in rows)
    assert configs == 0
    command.downgrade(alembic_config(engine), "0024")
    with engine.connect() as connection:
        assert {t: connection.exec_driver_sql(held.format(t)).all() for t in before} == before
        assert "label_configs" not in sa.inspect(connection).get_table_names()
    engine.dispose()
