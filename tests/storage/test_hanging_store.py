"""An object store that accepts connections and never answers holds nobody long: a request's
calls wait WELDPOOL_STORAGE_CONNECT_TIMEOUT_S / WELDPOOL_STORAGE_REQUEST_TIMEOUT_S for
WELDPOOL_STORAGE_REQUEST_ATTEMPTS tries (it was 60 s × 5: a one-frame upload answered its 503
after 367 s and `serve` took 368 s to start), and /health names the store."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.errors import ConfigurationError
from app.core.models import Role
from app.storage import open_storage
from tests.helpers import auth, hanging_server, image_bytes, make_settings, within


@pytest.fixture
def database_url(tmp_path: Path) -> str:
    """SQLite alone: the store, not the database, is what this module is about."""
    return f"sqlite:///{tmp_path / 'weldpool.sqlite3'}"


@pytest.fixture
def hanging_endpoint() -> Iterator[str]:
    with hanging_server() as endpoint:
        yield endpoint


@pytest.fixture
def settings(tmp_path: Path, database_url: str, hanging_endpoint: str) -> Settings:
    return make_settings(
        tmp_path / "home",
        database_url=database_url,
        storage_url="s3://hanging/lab",
        s3_endpoint_url=hanging_endpoint,
        storage_connect_timeout_s=1.0,
        storage_request_timeout_s=1.0,
        storage_request_attempts=2,
    )


def _bound(settings: Settings) -> float:
    """Three times the longest a request's call may wait on the store: generous, not a
    benchmark (the old waits were 300 s and more)."""
    waits = settings.storage_waits(jobs=False)
    return 3 * waits.attempts * (waits.connect_s + waits.read_s)


def test_an_upload_to_a_store_that_never_answers_is_a_503_within_the_bound(
    client: TestClient, make_user, settings: Settings
) -> None:
    _, token = make_user("rev", Role.reviewer)
    # eight frames: ingest's threads wait on the store at once, not one after another
    files = [("files", (f"{i}.png", image_bytes(seed=i), "image/png")) for i in range(8)]
    answer = within(
        _bound(settings), lambda: client.post("/api/v1/frames", files=files, headers=auth(token))
    )
    assert answer.status_code == 503, answer.text
    assert (
        answer.json()["detail"] == "The object store did not answer as expected; try again shortly."
    )
    assert "127.0.0.1" not in answer.text


def test_health_reports_a_store_that_never_answers(client: TestClient, settings: Settings) -> None:
    answer = within(_bound(settings), lambda: client.get("/api/v1/health"))
    assert answer.status_code == 503
    body = answer.json()
    assert body["status"] == "error"
    assert body["storage"]["status"] == "error" and body["storage"]["backend"] == "s3"
    assert body["storage"]["detail"] == (
        "The object store cannot be used (it did not answer within 4 s); check "
        "WELDPOOL_STORAGE_URL, WELDPOOL_S3_ENDPOINT_URL and the AWS_* credentials."
    )
    again = within(_bound(settings), lambda: client.get("/api/v1/health"))
    assert again.json()["storage"] == body["storage"]  # the check's answer, kept a few seconds


def test_starting_against_a_store_that_never_answers_stops_within_the_bound(
    settings: Settings,
) -> None:
    from app.cli.service import prepare_instance

    failure = within(_bound(settings), lambda: prepare_instance(settings))
    assert isinstance(failure, ConfigurationError), failure
    assert str(failure) == (
        "The object store s3://hanging/lab cannot be used (it did not answer within 4 s); "
        "check WELDPOOL_STORAGE_URL, WELDPOOL_S3_ENDPOINT_URL and the AWS_* credentials."
    )


def test_requests_and_jobs_wait_on_the_store_as_configured(settings: Settings) -> None:
    """Requests wait the short bounds; workers' jobs (open_storage) the longer ones."""
    request_store = open_storage(settings, for_requests=True)
    job_store = open_storage(settings)
    for store, waits in (
        (request_store, settings.storage_waits(jobs=False)),
        (job_store, settings.storage_waits(jobs=True)),
    ):
        config = store.objects.client.meta.config  # type: ignore[attr-defined]
        assert (config.connect_timeout, config.read_timeout) == (waits.connect_s, waits.read_s)
        assert config.retries["total_max_attempts"] == waits.attempts
    assert settings.storage_waits(jobs=True).read_s == 60.0
