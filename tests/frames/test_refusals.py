"""`POST /frames` when no file could be stored: a 422 whose body is what the schema documents."""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.core.models import Role
from tests.helpers import auth


def test_an_upload_with_nothing_stored_lists_each_refused_file_under_errors(
    client: TestClient, make_user
) -> None:
    _, token = make_user("uploader", Role.annotator)
    files = [
        ("files", ("notes.txt", b"not an image", "text/plain")),
        ("files", ("half.png", b"\x89PNG\r\n\x1a\n\x00\x00", "image/png")),
    ]
    answer = client.post("/api/v1/frames", files=files, headers=auth(token))
    assert answer.status_code == 422, answer.text
    body = answer.json()
    documented = client.app.openapi()["components"]["schemas"]["HTTPValidationError"]  # type: ignore[attr-defined]
    assert set(documented["required"]) <= body.keys()
    assert body["detail"].startswith("No frame was stored; notes.txt: ")
    reasons = {r["name"]: r["reason"] for r in body["rejected"]}
    assert body["errors"] == [
        {"loc": ["files", "notes.txt"], "msg": reasons["notes.txt"]},
        {"loc": ["files", "half.png"], "msg": reasons["half.png"]},
    ]
    assert body["stored"] == [] and body["duplicates"] == []
