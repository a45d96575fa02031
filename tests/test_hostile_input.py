"""Hostile input never reaches the database as a 500: huge ids and offsets, null where a value
is required, NUL characters, NaN and Infinity, oversized lists — on SQLite and PostgreSQL."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient

from app.core.bounds import MAX_ID
from app.core.models import Role
from tests.helpers import auth


@pytest.fixture
def admin(make_user) -> str:
    return str(make_user("boss", Role.admin)[1])


@pytest.mark.parametrize("number", [MAX_ID + 1, 2**63, -(2**63) - 1, 2**70])
def test_huge_ids_and_offsets_are_4xx_on_every_endpoint(
    client: TestClient, admin: str, number: int
) -> None:
    schema = client.app.openapi()  # type: ignore[attr-defined]
    checked = 0
    for path, operations in schema["paths"].items():
        for method in operations:
            if "{" in path:
                url = re.sub(r"\{[^}]+\}", str(number), path)
                response = client.request(method.upper(), url, headers=auth(admin), json={})
                assert 400 <= response.status_code < 500, (method, url, response.status_code)
                checked += 1
            if method == "get" and path.endswith(("/frames", "/jobs")):
                url = f"{path}?offset={number}"
                response = client.get(url, headers=auth(admin))
                assert response.status_code == 422, (url, response.status_code)
                checked += 1
    assert checked >= 20
    too_big = client.get("/api/v1/frames", params={"sequence_id": number}, headers=auth(admin))
    assert too_big.status_code == 422
    run = client.post("/api/v1/teacher/runs", json={"frame_ids": [1, number]}, headers=auth(admin))
    assert run.status_code == 422


def test_the_largest_id_is_a_plain_404(client: TestClient, admin: str) -> None:
    for path in ("/api/v1/frames", "/api/v1/jobs", "/api/v1/sequences", "/api/v1/models"):
        response = client.get(f"{path}/{MAX_ID}", headers=auth(admin))
        assert response.status_code == 404, (path, response.text)


def test_an_unknown_run_named_in_a_body_or_query_is_its_404(client: TestClient, admin: str) -> None:
    """Was a 400 that blamed the run's content ("has no frames", "no labels to export") or a
    200 that assigned nothing."""
    headers, run = auth(admin), MAX_ID
    for method, url, body in (
        ("POST", "/api/v1/teacher/runs", {"sequence_id": run}),
        ("POST", "/api/v1/exports", {"sequence_id": run}),
        ("GET", f"/api/v1/export?sequence_id={run}", None),
        ("POST", "/api/v1/frames/assign", {"next": 2, "sequence_id": run, "assignee_id": None}),
    ):
        answer = client.request(method, url, json=body, headers=headers)
        assert answer.status_code == 404, (url, answer.text)
        assert answer.json()["detail"] == f"There is no sequence {run}.", url


def test_a_422_speaks_of_the_request_not_of_pydantic(client: TestClient, admin: str) -> None:
    """A value outside a union of choices lists them all (it named pydantic's union member
    and left two choices out); malformed JSON says so (it said "1: JSON decode error"). A
    validator's sentence comes without pydantic's "Value error, " (test_bounded_input)."""
    headers = auth(admin)
    bogus = client.get("/api/v1/frames", params={"status": "bogus"}, headers=headers)
    assert bogus.status_code == 422
    assert bogus.json()["detail"] == (
        "status: Input should be one of new, proposed, accepted, corrected, rejected, "
        "unreviewed, all."
    )
    broken = client.post(
        "/api/v1/sequences",
        content=b'{"name": ',
        headers=headers | {"Content-Type": "application/json"},
    )
    assert broken.status_code == 422
    assert broken.json()["detail"] == "The request body is not valid JSON."


def test_null_nul_nan_and_oversized_bodies_are_422(client: TestClient, admin: str) -> None:
    created = client.post("/api/v1/sequences", json={"name": "run 1"}, headers=auth(admin))
    assert created.status_code == 201
    sequence = created.json()["id"]
    url = f"/api/v1/sequences/{sequence}"
    for body in ({"name": None}, {"notes": None}):
        response = client.patch(url, json=body, headers=auth(admin))
        assert response.status_code == 422, response.text
        assert "cannot be null" in response.json()["detail"]
    assert client.patch(url, json={"voltage_v": None}, headers=auth(admin)).status_code == 200

    nul = client.post("/api/v1/sequences", json={"name": "a\x00b"}, headers=auth(admin))
    assert nul.status_code == 422 and "NUL" in nul.json()["detail"]
    assert client.patch(url, json={"notes": "x\x00"}, headers=auth(admin)).status_code == 422
    user = client.post(
        "/api/v1/users", json={"username": "eve", "password": "pass\x00word1"}, headers=auth(admin)
    )
    assert user.status_code == 422

    for literal in ("NaN", "Infinity", "-Infinity"):
        raw = '{"name": "run ' + literal + '", "voltage_v": ' + literal + "}"
        response = client.post(
            "/api/v1/sequences",
            content=raw,
            headers={**auth(admin), "content-type": "application/json"},
        )
        assert response.status_code == 422, (literal, response.text)
    names = [s["name"] for s in client.get("/api/v1/sequences", headers=auth(admin)).json()]
    assert names == ["run 1"]

    frame = f"/api/v1/frames/{MAX_ID}"
    many = [[1.0, 2.0]] * 300_000
    label = client.put(
        f"{frame}/label",
        json={"status": "corrected", "base_revision": 0, "keypoints": many},
        headers=auth(admin),
    )
    assert label.status_code == 422
    three = client.put(
        f"{frame}/validation-keypoints", json={"keypoints": [[1, 2, 3]]}, headers=auth(admin)
    )
    assert three.status_code == 422
    click = client.post(
        f"{frame}/segment",
        content='{"points": [{"x": NaN, "y": 1}]}',
        headers={**auth(admin), "content-type": "application/json"},
    )
    assert click.status_code == 422
