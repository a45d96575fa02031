"""Fixtures for an app whose teacher is the real code on tiny random-weight models saved locally
(imported by the conftest of each domain that runs the teacher)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.main import create_app
from tests.helpers import make_settings
from tests.models import save_tiny_teacher


@pytest.fixture(scope="session")
def teacher_weights(tmp_path_factory) -> dict[str, object]:
    return save_tiny_teacher(tmp_path_factory.mktemp("teacher-weights"))


@pytest.fixture
def settings(tmp_path: Path, database_url: str, teacher_weights) -> Settings:
    return make_settings(tmp_path / "home", database_url=database_url, **teacher_weights)


@pytest.fixture
def client(settings: Settings, session_factory) -> Iterator[TestClient]:
    with TestClient(create_app(settings, embedded_worker=True)) as test_client:
        yield test_client
