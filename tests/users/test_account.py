"""One's own password (`POST /users/me/password`), last logins, and the users and account
pages' access rules."""

from __future__ import annotations

import re

from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import form_login
from tests.helpers import auth


def _csrf(client: TestClient) -> str:
    match = re.search(r'<meta name="csrf-token" content="([^"]+)"', client.get("/").text)
    assert match
    return match.group(1)


def test_changing_ones_password_checks_the_current_one_and_ends_other_sessions(
    client: TestClient, make_user
) -> None:
    ines, token = make_user("ines", password="old-password")
    other = TestClient(client.app)
    assert form_login(other, "ines", "old-password").status_code == 303  # another browser
    assert form_login(client, "ines", "old-password").status_code == 303
    csrf = {"X-CSRF-Token": _csrf(client)}

    wrong = client.post(
        "/api/v1/users/me/password",
        json={"current": "guess-word", "new": "new-password"},
        headers=csrf,
    )
    assert (
        wrong.status_code == 403 and wrong.json()["detail"] == "The current password is not right."
    )
    short = client.post(
        "/api/v1/users/me/password", json={"current": "old-password", "new": "short"}, headers=csrf
    )
    assert short.status_code in (400, 422) and "8" in short.json()["detail"]
    same = client.post(
        "/api/v1/users/me/password",
        json={"current": "old-password", "new": "old-password"},
        headers=csrf,
    )
    assert same.status_code == 400 and "in use" in same.json()["detail"]
    assert other.get("/api/v1/users/me").status_code == 200  # nothing changed yet

    changed = client.post(
        "/api/v1/users/me/password",
        json={"current": "old-password", "new": "new-password"},
        headers=csrf,
    )
    assert changed.status_code == 200
    assert changed.json() == {"sessions_ended": 1, "tokens_active": 1}
    assert other.get("/api/v1/users/me").status_code == 401  # the other browser is logged out
    assert client.get("/api/v1/users/me").json()["username"] == "ines"  # this one stays
    assert client.get("/api/v1/users/me", headers=auth(token)).status_code == 200  # tokens stay
    fresh = TestClient(client.app)
    assert form_login(fresh, "ines", "old-password").status_code == 401
    assert form_login(fresh, "ines", "new-password").status_code == 303
    assert ines.id


def test_wrong_current_passwords_count_towards_the_lockout(client: TestClient, make_user) -> None:
    _, token = make_user("jon", password="right-password")
    limit = client.app.state.settings.login_max_failures  # type: ignore[attr-defined]
    body = {"current": "wrong-password", "new": "another-password"}
    for _ in range(limit):
        assert (
            client.post("/api/v1/users/me/password", json=body, headers=auth(token)).status_code
            == 403
        )
    body["current"] = "right-password"
    locked = client.post("/api/v1/users/me/password", json=body, headers=auth(token))
    assert locked.status_code == 429 and "Too many wrong passwords" in locked.json()["detail"]


def test_last_login_is_recorded_by_the_form_and_by_a_password_token(
    client: TestClient, make_user
) -> None:
    _, admin = make_user("kim", Role.admin)
    make_user("lea", password="lea-password")
    make_user("max", password="max-password")
    listed = {u["username"]: u for u in client.get("/api/v1/users", headers=auth(admin)).json()}
    assert listed["lea"]["last_login_at"] is None and listed["max"]["last_login_at"] is None
    assert form_login(client, "lea", "lea-password").status_code == 303
    assert (
        form_login(TestClient(client.app), "max", "wrong-password").status_code == 401
    )  # a failure is no login
    after = {u["username"]: u for u in client.get("/api/v1/users", headers=auth(admin)).json()}
    assert after["lea"]["last_login_at"] is not None and after["max"]["last_login_at"] is None
    scripted = TestClient(client.app).post(
        "/api/v1/tokens", json={"username": "max", "password": "max-password"}
    )
    assert scripted.status_code == 201
    final = {u["username"]: u for u in client.get("/api/v1/users", headers=auth(admin)).json()}
    assert final["max"]["last_login_at"] is not None


def test_the_users_page_is_for_admins_and_the_account_page_for_everyone(
    client: TestClient, make_user
) -> None:
    make_user("nia", Role.admin, password="nia-password")
    make_user("ola", Role.reviewer, password="ola-password")
    assert form_login(client, "ola", "ola-password").status_code == 303
    refused = client.get("/users")
    assert refused.status_code == 403 and "Only admins manage users" in refused.text
    assert 'data-testid="nav-users"' not in client.get("/").text
    account = client.get("/account")
    assert account.status_code == 200 and 'data-testid="password-form"' in account.text
    admin = TestClient(client.app)
    assert form_login(admin, "nia", "nia-password").status_code == 303
    page = admin.get("/users")
    assert page.status_code == 200 and 'data-testid="user-table"' in page.text
    assert 'data-testid="nav-users"' in admin.get("/").text


def test_the_schema_offers_a_bearer_token_to_every_operation_but_health(
    client: TestClient, make_user
) -> None:
    _, token = make_user("pia")
    schema = client.get("/api/v1/openapi.json", headers=auth(token)).json()
    assert schema["components"]["securitySchemes"]["bearer"] == {
        "type": "http",
        "scheme": "bearer",
        "description": schema["components"]["securitySchemes"]["bearer"]["description"],
    }
    assert schema["security"] == [{"bearer": []}]
    assert schema["paths"]["/api/v1/health"]["get"]["security"] == []
    assert "security" not in schema["paths"]["/api/v1/frames"]["get"]  # the global one holds


def test_a_page_from_an_earlier_login_learns_the_sessions_csrf_token(
    client: TestClient, make_user
) -> None:
    """A page holds the CSRF token of the login it was loaded under; after a new login its
    changes are refused with ``reason: csrf``, and ``GET /users/me/csrf`` gives the session's
    token, with which they pass (an API token has none; no session: 401)."""
    _, token = make_user("ines", password="old-password")
    assert form_login(client, "ines", "old-password").status_code == 303
    stale = _csrf(client)
    client.post("/logout", data={"csrf_token": stale})
    assert client.get("/api/v1/users/me/csrf").status_code == 401
    assert form_login(client, "ines", "old-password").status_code == 303
    body = {"name": "a run"}
    refused = client.post("/api/v1/sequences", json=body, headers={"X-CSRF-Token": stale})
    assert refused.status_code == 403 and refused.json()["reason"] == "csrf"
    fresh = client.get("/api/v1/users/me/csrf")
    assert fresh.headers["cache-control"] == "no-store"
    assert fresh.json()["csrf_token"] == _csrf(client) != stale
    assert fresh.json()["username"] == "ines"
    headers = {"X-CSRF-Token": fresh.json()["csrf_token"]}
    assert client.post("/api/v1/sequences", json=body, headers=headers).status_code == 201
    assert TestClient(client.app).get("/api/v1/users/me/csrf", headers=auth(token)).json() == {
        "csrf_token": None,
        "username": "ines",
    }
