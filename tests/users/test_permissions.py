"""One table of who may do what (``app.core.permissions``): routes, services and the browser
read it, so a rule changed there changes it everywhere."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from app.core import permissions
from app.core.models import Role
from app.core.permissions import Action
from tests.factories import form_login
from tests.helpers import auth


def test_each_role_is_told_what_it_may_do(client: TestClient, make_user) -> None:
    expected = {
        Role.annotator: ["label"],
        Role.reviewer: ["label", "review", "cancel_any_job"],
        Role.admin: ["label", "review", "cancel_any_job", "administer"],
    }
    for role, may in expected.items():
        _, token = make_user(f"user-{role.value}", role)
        me = client.get("/api/v1/users/me", headers=auth(token)).json()
        assert me["role"] == role.value and me["may"] == may


def test_the_table_decides_routes_and_services(
    client: TestClient, make_user, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An annotator cannot delete frames (a reviewer's action) until the table lets her
    review; the same table then lists `review` for her."""
    _, token = make_user("ann", Role.annotator)
    refused = client.post("/api/v1/frames/delete", json={"frame_ids": [1]}, headers=auth(token))
    assert refused.status_code == 403
    assert refused.json()["detail"] == "This needs the reviewer role or higher; you are annotator."
    monkeypatch.setitem(permissions.PERMISSIONS, Action.review, Role.annotator)
    allowed = client.post("/api/v1/frames/delete", json={"frame_ids": [1]}, headers=auth(token))
    assert allowed.status_code == 404  # past the role check: there is no frame 1
    assert "review" in client.get("/api/v1/users/me", headers=auth(token)).json()["may"]


def test_pages_carry_what_the_server_decides(client: TestClient, make_user) -> None:
    """Each page says what its user may do (the table's actions) and the review page how many
    keypoints a validation set places (Algorithm 1's k): nothing of either is typed into the
    pages' JavaScript."""
    import re

    from weldpool_core.heatmap import HeatmapParams

    make_user("rev", Role.reviewer, password="correct horse")
    assert form_login(client, "rev", "correct horse").status_code == 303
    page = client.get("/frames/1").text
    assert re.search(r'<meta name="user-may" content="label,review,cancel_any_job">', page)
    assert f'data-keypoints="{HeatmapParams().k}"' in page
