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
    # The test settings name no teacher weights: usable, but degraded, and it says how to fix it.
    assert body["status"] == "degraded"
    assert body["warnings"] == [
        "The teacher cannot run: its weights are missing (WELDPOOL_DINO and WELDPOOL_SAM2). Run "
        "`weldpool weights fetch` on a machine with internet access, or point WELDPOOL_DINO and "
        "WELDPOOL_SAM2 at a local folder, then restart."
    ]
    assert body["database"]["status"] == "ok" and body["database"]["revision"]
    assert body["queue"] == body["queue"] | {"status": "ok", "backend": "sqlite", "pending": 0}
    assert body["queue"]["alive"] == 1  # the embedded worker
    assert body["storage"] == {"status": "ok", "backend": "local"}  # home can be written
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


def test_health_is_ok_with_the_teacher_weights_and_a_worker(tmp_path: Path) -> None:
    from app.core.db import create_db_engine
    from app.core.schema import migrate
    from tests.models import save_tiny_teacher

    weights = save_tiny_teacher(tmp_path / "weights")
    settings = make_settings(tmp_path / "home", dino=weights["dino"], sam2=weights["sam2"])
    migrate(create_db_engine(settings.resolved_database_url))
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        answer = client.get("/api/v1/health")
    body = answer.json()
    assert body["status"] == "ok" and body["warnings"] == []
    assert str(tmp_path) not in answer.text  # /health answers anyone: no path of this machine
    assert body["teacher"]["sam2"]["ref"] == Path(weights["sam2"]).name


def test_health_checks_the_object_store(tmp_path: Path, s3_url: str, s3_endpoint: str) -> None:
    settings = make_settings(tmp_path, storage_url=s3_url, s3_endpoint_url=s3_endpoint)
    with TestClient(create_app(settings)) as client:
        body = client.get("/api/v1/health").json()
    assert body["storage"] == {"status": "ok", "backend": "s3"}
