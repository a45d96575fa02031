"""Database engine, sessions and schema migrations (SQLite by default, PostgreSQL for real)."""

from __future__ import annotations

import datetime as dt
import enum
import functools
import re
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import sqlalchemy as sa
from sqlalchemy.dialects.sqlite.base import SQLiteCompiler
from sqlalchemy.engine import Engine
from sqlalchemy.orm import DeclarativeBase, Session, sessionmaker

from app.core.errors import ConfigurationError, ConflictError

if TYPE_CHECKING:  # alembic is imported only when a schema must change (0.1–0.2 s at start-up)
    from alembic.config import Config

MIGRATIONS_DIR = Path(__file__).resolve().parents[2] / "migrations"


def utcnow() -> dt.datetime:
    """The current time, timezone-aware in UTC."""
    return dt.datetime.now(dt.UTC)


def db_now(dialect: str) -> Any:
    """Now by the database's clock, for heartbeats and their staleness: workers on several
    machines compare their beats on one clock (a worker whose clock ran 90 s behind had its live
    job reaped). PostgreSQL's statement time in UTC; SQLite lives on one machine, whose clock
    every process that writes it shares."""
    if dialect == "postgresql":
        return sa.func.timezone("UTC", sa.func.statement_timestamp(), type_=sa.DateTime)
    return utcnow()


class UTCDateTime(sa.types.TypeDecorator[dt.datetime]):
    """Stores naive UTC, returns aware UTC, on every backend (SQLite keeps no time zones)."""

    impl = sa.DateTime
    cache_ok = True

    def process_bind_param(self, value: dt.datetime | None, dialect: Any) -> dt.datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetimes are ambiguous; pass an aware UTC datetime")
        return value.astimezone(dt.UTC).replace(tzinfo=None)

    def process_result_value(self, value: dt.datetime | None, dialect: Any) -> dt.datetime | None:
        return None if value is None else value.replace(tzinfo=dt.UTC)


class Base(DeclarativeBase):
    """Declarative base of every table."""

    metadata = sa.MetaData(
        naming_convention={
            "ix": "ix_%(column_0_label)s",
            "uq": "uq_%(table_name)s_%(column_0_name)s",
            "ck": "ck_%(table_name)s_%(constraint_name)s",
            "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
            "pk": "pk_%(table_name)s",
        }
    )


class _SQLiteCompiler(SQLiteCompiler):
    """SQLite's compiler, writing a query's table hint (``with_hint(…, "sqlite")``) after the
    table's name, where SQLAlchemy's drops it: ``INDEXED BY`` names the index a list reads."""

    def get_from_hint_text(self, table: Any, text: str | None) -> str | None:
        return text


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA busy_timeout=10000")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.close()


def commit_or_conflict(session: Session, message: str) -> None:
    """Commit; a unique constraint hit by a concurrent writer becomes ConflictError(message).

    Checks before an insert ("is the name free?") cannot see a writer that commits between the
    check and this commit; the database's constraint does, and this turns it into a 409.
    """
    try:
        session.commit()
    except sa.exc.IntegrityError:
        session.rollback()
        raise ConflictError(message) from None


def create_db_engine(url: str) -> Engine:
    """An engine for ``url``; SQLite files get WAL mode, foreign keys and a busy timeout."""
    try:
        parsed = sa.engine.make_url(url)
    except sa.exc.ArgumentError as exc:
        raise ConfigurationError(f"WELDPOOL_DATABASE_URL is not a database URL ({url!r}).") from exc
    if parsed.get_backend_name() == "sqlite":
        if parsed.database and parsed.database != ":memory:":
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        engine = sa.create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})
        sa.event.listen(engine, "connect", _sqlite_pragmas)
        engine.dialect.statement_compiler = _SQLiteCompiler
        return engine
    if parsed.get_backend_name() != "postgresql":
        raise ConfigurationError(
            "WELDPOOL_DATABASE_URL must be a sqlite:/// or postgresql+psycopg:// URL."
        )
    return sa.create_engine(url, pool_pre_ping=True)


def create_session_factory(engine: Engine) -> sessionmaker[Session]:
    """Sessions that keep loaded attributes after commit (the API returns them afterwards)."""
    return sessionmaker(engine, expire_on_commit=False)


@contextmanager
def session_scope(factory: sessionmaker[Session]) -> Iterator[Session]:
    """A session that commits on success and rolls back on error (for workers and the CLI)."""
    session = factory()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


def alembic_config(engine: Engine) -> Config:
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.attributes["engine"] = engine
    return config


_REVISION = re.compile(r"^(down_revision|revision)\s*(?::[^=]*)?=\s*(.+)$", re.MULTILINE)
_QUOTED = re.compile(r"'([^']+)'|\"([^\"]+)\"")


@functools.cache
def head_revision() -> str:
    """The newest revision the code knows, read from the migration files' ``revision`` and
    ``down_revision`` lines (alembic's ScriptDirectory gives the same: a test checks), so a
    process whose database is current never imports alembic."""
    revisions: set[str] = set()
    parents: set[str] = set()
    for path in (MIGRATIONS_DIR / "versions").glob("*.py"):
        for name, value in _REVISION.findall(path.read_text(encoding="utf-8")):
            named = {a or b for a, b in _QUOTED.findall(value)}  # None, 'x' or ('x', 'y')
            (revisions if name == "revision" else parents).update(named)
    heads = revisions - parents
    if len(heads) != 1:  # a branch point (or an unreadable file): alembic decides
        from alembic.script import ScriptDirectory

        return ScriptDirectory(str(MIGRATIONS_DIR)).get_current_head() or ""
    return heads.pop()


def current_revision(engine: Engine) -> str | None:
    """The database's revision (alembic's version table), None before the first migration."""
    if not sa.inspect(engine).has_table("alembic_version"):
        return None
    with engine.connect() as connection:
        return connection.execute(sa.text("SELECT version_num FROM alembic_version")).scalar()


def schema_revision(engine: Engine) -> tuple[str | None, str]:
    """(the database's current revision, the newest revision the code knows)."""
    return current_revision(engine), head_revision()


def require_current_schema(engine: Engine) -> None:
    """Raise a clear error when the database is not migrated to the newest revision."""
    current, head = schema_revision(engine)
    if current != head:
        raise ConfigurationError(
            f"The database schema is at revision {current or 'none'}, not {head}; "
            "run `weldpool migrate` first."
        )


def changed(session: Session, statement: sa.Executable) -> int:
    """Run an UPDATE or DELETE and say how many rows it changed: the one place that reads a
    result's row count (a compare-and-set's conditional write took its row, or another writer
    was first)."""
    result = cast("sa.CursorResult[Any]", session.execute(statement))
    return int(result.rowcount)


def updated_one(session: Session, statement: sa.Executable) -> bool:
    """Run a conditional UPDATE or DELETE (a compare-and-set): True when it took its one row."""
    return changed(session, statement) == 1


JSONType = sa.JSON()
"""The JSON column type of every table."""


_tables_seen: dict[str, weakref.WeakSet[Any]] = {}
"""Per table, the engines known to hold it (an older schema, mid-migration, has fewer)."""


def has_table(session: Session, name: str) -> bool:
    """Whether the session's database has table ``name`` (asked once per engine while it has)."""
    bind = session.get_bind()
    engine = getattr(bind, "engine", bind)
    seen = _tables_seen.setdefault(name, weakref.WeakSet())
    if engine not in seen:
        if not sa.inspect(session.connection()).has_table(name):
            return False
        seen.add(engine)
    return True


def enum_type(cls: type[enum.StrEnum], name: str) -> sa.Enum:
    """An enum column type: stored as plain strings with a CHECK constraint (portable, and easy
    to extend by migration)."""
    return sa.Enum(
        cls,
        name=name,
        native_enum=False,
        length=16,
        validate_strings=True,
        values_callable=lambda e: [m.value for m in e],
    )
