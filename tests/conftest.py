"""Shared fixtures: settings per test, SQLite and the real PostgreSQL, clients and users.

PostgreSQL and Redis are used for real; when they are unreachable the tests that need them
fail with a clear message (CI must not pass without them).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role, User
from app.core.schema import migrate
from app.core.security import hash_password, issue_token
from app.main import create_app
from tests.helpers import REDIS_URL, make_settings, postgres_schema
from tests.mqtt import mqtt_broker  # noqa: F401 (the broker fixture for every test)
from tests.s3 import s3_endpoint, s3_url  # noqa: F401 (fixtures for every test)

if TYPE_CHECKING:  # the student fixtures import torch only when a test asks for one
    from weldpool_core.student.data import TrainingFrame
    from weldpool_core.student.train import TrainResult


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """A URL whose connections live in a fresh schema of the real PostgreSQL, dropped after."""
    with postgres_schema() as url:
        yield url


@pytest.fixture
def redis_url() -> str:
    """The real Redis; fails (not skips) when it is unreachable."""
    import redis

    try:
        redis.Redis.from_url(REDIS_URL).ping()
    except redis.exceptions.ConnectionError as exc:
        pytest.fail(
            f"Redis at {REDIS_URL} is unreachable ({exc}); start it or set "
            "WELDPOOL_TEST_REDIS_URL.",
            pytrace=False,
        )
    return REDIS_URL


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """Each test that uses it runs twice: on a SQLite file and on the real PostgreSQL."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'weldpool.sqlite3'}"
    return str(request.getfixturevalue("postgres_url"))


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return make_settings(tmp_path / "home", database_url=database_url)


@pytest.fixture
def session_factory(settings: Settings) -> Iterator[Any]:
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    yield create_session_factory(engine)
    engine.dispose()


@pytest.fixture
def client(settings: Settings, session_factory: Any) -> Iterator[TestClient]:
    """The app with its embedded worker, as `weldpool serve` runs it."""
    app = create_app(settings, embedded_worker=True)
    with TestClient(app) as test_client:
        yield test_client


@pytest.fixture
def make_user(session_factory: Any) -> Callable[..., tuple[User, str]]:
    """Create a user with a role; returns the user and a bearer token."""

    def make(
        name: str, role: Role = Role.annotator, password: str = "correct horse"
    ) -> tuple[User, str]:
        with session_factory() as session:
            user = User(username=name, password_hash=hash_password(password), role=role)
            session.add(user)
            session.flush()
            _, token = issue_token(session, user, "test")
            session.commit()
            return user, token

    return make


@pytest.fixture(scope="session")
def tiny_frames() -> list[TrainingFrame]:
    """Eight tiny synthetic frames (96×64, one weld run each)."""
    from tests.core.student.common import synthetic_frames

    return synthetic_frames(8)


@pytest.fixture(scope="session")
def sure_student(
    tmp_path_factory: pytest.TempPathFactory, tiny_frames: list[TrainingFrame]
) -> TrainResult:
    """A light student trained for 800 steps on the eight tiny frames: sure of frames like
    them (mIoU about 0.9 on other runs), so that what raises its uncertainty can be seen, and
    crisp enough for an int8 student to match it (IoU 0.99; 0.965 after 100 steps). Trained
    once for the whole run: a test that changes its folder copies it first."""
    from tests.core.student.common import TINY_STUDENT, tiny_config
    from weldpool_core.student.train import train_student

    out = tmp_path_factory.mktemp("sure-student") / "model"
    config = tiny_config(epochs=None, steps=800, rounds=4)
    return train_student(tiny_frames, out, TINY_STUDENT, config)


@pytest.fixture(scope="session")
def sure_latent_student(
    tmp_path_factory: pytest.TempPathFactory, tiny_frames: list[TrainingFrame]
) -> TrainResult:
    """``sure_student`` without skips: everything it draws passes through its latent, the
    state a sequential cell carries (a skip student's finer maps come from each frame)."""
    from tests.core.student.common import TINY_STUDENT, tiny_config
    from weldpool_core.student.train import train_student

    out = tmp_path_factory.mktemp("sure-latent-student") / "model"
    config = tiny_config(epochs=None, steps=800, rounds=4)
    return train_student(tiny_frames, out, replace(TINY_STUDENT, skips=0), config)
