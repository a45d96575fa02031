"""/api/v1/health needs no login and tells what is wrong."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from app.main import create_app
from tests.helpers import make_settings


def test_health_reports_database_queue_and_teacher(client: TestClient) -> None:
    response = client.get("/api/v1/health")
    assert response.status_code == 200
    body = response.json()
    assert body["status"] == "ok"
    assert body["database"]["status"] == "ok" and body["database"]["revision"]
    assert body["queue"] == body["queue"] | {"status": "ok", "backend": "sqlite", "pending": 0}
    assert body["queue"]["alive"] == 1  # the embedded worker
    assert set(body["teacher"]) == {"dino", "sam2"}
    assert body["teacher"]["sam2"]["setting"] == "WELDPOOL_SAM2"


def test_health_is_503_when_the_database_is_unreachable(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, database_url="postgresql+psycopg://x@127.0.0.1:1/none")
    with TestClient(create_app(settings)) as client:
        response = client.get("/api/v1/health")
    assert response.status_code == 503
    body = response.json()
    assert body["status"] == "error" and body["database"]["status"] == "error"


def test_health_is_503_when_the_schema_is_not_migrated(tmp_path: Path) -> None:
    with TestClient(create_app(make_settings(tmp_path))) as client:
        body = client.get("/api/v1/health").json()
    assert body["database"]["status"] == "error" and body["database"]["revision"] is None
