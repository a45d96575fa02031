"""Authentication and roles: tokens, browser sessions with CSRF, 401 and 403."""

from __future__ import annotations

import re

import httpx
import pytest
import sqlalchemy as sa
from argon2 import PasswordHasher
from fastapi.testclient import TestClient

from app.core import security
from app.core.models import Role, User
from app.users.service import ensure_initial_admin
from tests.factories import form_login
from tests.helpers import auth

PUBLIC_PATHS = {"/api/v1/health", "/login"}


PAGES = [
    *(("GET", "/"), ("POST", "/logout"), ("GET", "/docs"), ("GET", "/api/v1/openapi.json")),
    *(("GET", "/help"), ("GET", "/help/guides/reviewing"), ("GET", "/help/images/review.png")),
]


def _protected_routes(client: TestClient) -> list[tuple[str, str]]:
    """Every operation of the OpenAPI schema, and the pages that are not in it."""
    schema = client.app.openapi()  # type: ignore[attr-defined]
    routes = [
        (method.upper(), path)
        for path, operations in schema["paths"].items()
        if path not in PUBLIC_PATHS
        for method in operations
    ]
    return routes + PAGES


def test_every_endpoint_but_health_and_login_needs_a_user(client: TestClient) -> None:
    routes = _protected_routes(client)
    assert len(routes) > 10
    for method, path in routes:
        url = re.sub(r"\{[^}]+\}", "1", path)
        response = client.request(
            method, url, headers={"accept": "application/json"}, follow_redirects=False
        )
        assert response.status_code == 401, (method, path, response.status_code)
        assert "detail" in response.json()
    assert client.get("/api/v1/health").status_code == 200
    assert client.get("/login").status_code == 200


def test_a_page_redirects_a_browser_to_login(client: TestClient) -> None:
    response = client.get("/", headers={"accept": "text/html"}, follow_redirects=False)
    assert response.status_code == 303
    assert response.headers["location"] == "/login?next=/"


def test_token_works_and_revoked_token_does_not(client: TestClient, make_user) -> None:
    _, token = make_user("ana", Role.annotator)
    me = client.get("/api/v1/users/me", headers=auth(token))
    assert me.status_code == 200 and me.json()["username"] == "ana"

    created = client.post("/api/v1/tokens", json={"name": "script"}, headers=auth(token)).json()
    second = created["token"]
    assert client.get("/api/v1/users/me", headers=auth(second)).status_code == 200
    listed = client.get("/api/v1/tokens", headers=auth(token)).json()
    assert {t["name"] for t in listed} == {"test", "script"}
    assert all("token" not in t for t in listed)

    revoked = client.delete(f"/api/v1/tokens/{created['id']}", headers=auth(token))
    assert revoked.status_code == 200 and revoked.json()["revoked_at"]
    response = client.get("/api/v1/users/me", headers=auth(second))
    assert response.status_code == 401
    assert response.json()["detail"] == "The API token is invalid or revoked; create a new one."
    assert client.get("/api/v1/users/me", headers=auth(token)).status_code == 200


def test_malformed_or_unknown_credentials_get_401(client: TestClient) -> None:
    for header in ("Bearer wp_nope", "Basic YWxpY2U6c2VjcmV0", "Bearer "):
        response = client.get("/api/v1/users/me", headers={"Authorization": header})
        assert response.status_code == 401, header
        assert response.headers["www-authenticate"] == "Bearer"


def test_wrong_role_gets_403(client: TestClient, make_user) -> None:
    _, annotator = make_user("ann", Role.annotator)
    _, reviewer = make_user("rev", Role.reviewer)
    _, admin = make_user("adm", Role.admin)
    body = {"username": "newbie", "password": "long enough", "role": "annotator"}
    for token in (annotator, reviewer):
        response = client.post("/api/v1/users", json=body, headers=auth(token))
        assert response.status_code == 403
        assert "admin role" in response.json()["detail"]
        assert (
            client.post("/api/v1/jobs/diagnostic", json={}, headers=auth(token)).status_code == 403
        )
    assert client.post("/api/v1/users", json=body, headers=auth(admin)).status_code == 201


def test_users_cannot_revoke_others_tokens(client: TestClient, make_user, session_factory) -> None:
    _, first = make_user("first")
    _, second = make_user("second")
    token_id = client.get("/api/v1/tokens", headers=auth(first)).json()[0]["id"]
    response = client.delete(f"/api/v1/tokens/{token_id}", headers=auth(second))
    assert response.status_code == 403
    assert client.get("/api/v1/users/me", headers=auth(first)).status_code == 200


def test_deactivated_user_is_locked_out(client: TestClient, make_user) -> None:
    _, admin = make_user("boss", Role.admin)
    user, token = make_user("leaver")
    patch = client.patch(f"/api/v1/users/{user.id}", json={"is_active": False}, headers=auth(admin))
    assert patch.status_code == 200
    assert client.get("/api/v1/users/me", headers=auth(token)).status_code == 401


def test_last_admin_cannot_be_demoted(client: TestClient, make_user) -> None:
    admin, token = make_user("only-admin", Role.admin)
    response = client.patch(
        f"/api/v1/users/{admin.id}", json={"role": "reviewer"}, headers=auth(token)
    )
    assert response.status_code == 409
    assert client.get("/api/v1/users/me", headers=auth(token)).json()["role"] == "admin"


def test_passwords_and_tokens_are_stored_hashed(client: TestClient, make_user, session_factory):
    _, token = make_user("hashy", password="correct horse")
    with session_factory() as session:
        from app.core.models import ApiToken

        user = session.query(User).filter_by(username="hashy").one()
        assert user.password_hash.startswith("$argon2id$")
        stored = [t.token_hash for t in session.query(ApiToken).all()]
    assert token not in stored and all(len(h) == 64 for h in stored)


def test_bad_input_gets_a_sentence_not_a_500(client: TestClient, make_user) -> None:
    _, admin = make_user("adm2", Role.admin)
    response = client.post("/api/v1/users", json={"username": "x"}, headers=auth(admin))
    assert response.status_code == 422
    assert response.json()["detail"] == "password: Field required."
    response = client.post(
        "/api/v1/users",
        content=b"{not json",
        headers=auth(admin) | {"content-type": "application/json"},
    )
    assert response.status_code == 422
    dup = {"username": "adm2", "password": "long enough", "role": "admin"}
    response = client.post("/api/v1/users", json=dup, headers=auth(admin))
    assert response.status_code == 409
    assert response.json()["detail"] == "There is already a user named 'adm2'."


# --- browser login -----------------------------------------------------------------------------


def test_login_session_cookie_and_csrf(client: TestClient, make_user) -> None:
    make_user("carla", Role.reviewer, password="s3cret-pass")
    response = form_login(client, "carla", "s3cret-pass", "/")
    assert response.status_code == 303 and response.headers["location"] == "/"
    cookie = response.cookies.get("weldpool_session")
    assert cookie
    assert "httponly" in response.headers["set-cookie"].lower()

    home = client.get("/")
    assert home.status_code == 200
    assert 'data-testid="current-user">carla<' in home.text
    assert 'data-testid="current-role">reviewer<' in home.text
    csrf = re.search(r'<meta name="csrf-token" content="([^"]+)"', home.text).group(1)

    # The session cookie authenticates API reads; writes also need the CSRF token.
    assert client.get("/api/v1/users/me").json()["username"] == "carla"
    refused = client.post("/api/v1/tokens", json={"name": "x"})
    assert refused.status_code == 403 and "CSRF" in refused.json()["detail"]
    accepted = client.post("/api/v1/tokens", json={"name": "x"}, headers={"X-CSRF-Token": csrf})
    assert accepted.status_code == 201

    # Logging out needs the form's token too, and ends the session for good.
    assert client.post("/logout", data={"csrf_token": "forged"}).status_code == 403
    out = client.post("/logout", data={"csrf_token": csrf}, follow_redirects=False)
    assert out.status_code == 303
    client.cookies.set("weldpool_session", cookie)
    assert client.get("/api/v1/users/me").status_code == 401


def test_wrong_password_and_forged_login_form(client: TestClient, make_user) -> None:
    make_user("dora", password="right-password")
    response = form_login(client, "dora", "wrong-password")
    assert response.status_code == 401
    assert "Wrong user name or password." in response.text
    assert "weldpool_session" not in response.cookies
    # The form keeps the name typed (escaped), so only the password is typed again.
    assert 'name="username" autocomplete="username" required maxlength="64" value="dora"' in (
        response.text
    )
    odd = form_login(client, '"><b>x', "whatever1")
    assert 'value="&#34;&gt;&lt;b&gt;x"' in odd.text and "<b>x" not in odd.text
    response = form_login(client, "nobody", "whatever1")
    assert response.status_code == 401

    forged = client.post(
        "/login",
        data={"username": "dora", "password": "right-password", "csrf_token": "guess"},
        follow_redirects=False,
    )
    assert forged.status_code == 403
    assert "weldpool_session" not in forged.cookies


def test_wrong_passwords_lock_the_name_out_for_a_while(client: TestClient, make_user) -> None:
    make_user("fred", password="right-password")
    make_user("gina", password="right-password")
    limit = client.app.state.settings.login_max_failures  # type: ignore[attr-defined]
    for _ in range(limit):
        assert form_login(client, "fred", "wrong-password").status_code == 401
    locked = form_login(
        client, "fred", "right-password"
    )  # even the right one, until the window ends
    assert locked.status_code == 429
    assert "Too many wrong passwords" in locked.text
    assert 0 < int(locked.headers["retry-after"]) <= 15 * 60
    assert "weldpool_session" not in locked.cookies
    # Another name from the same client still logs in, and a success clears its own count.
    assert form_login(client, "gina", "wrong-password").status_code == 401
    assert form_login(client, "gina", "right-password").status_code == 303
    throttle = client.app.state.login_throttle  # type: ignore[attr-defined]
    assert throttle.retry_after("gina", "testclient") == 0
    throttle.window_s = 0.0  # the window has passed
    client.cookies.clear()
    assert form_login(client, "fred", "right-password").status_code == 303


def test_a_password_reset_ends_sessions_and_revokes_tokens(client: TestClient, make_user) -> None:
    _, admin = make_user("root", Role.admin)
    hana, hana_token = make_user("hana", password="old-password")
    assert form_login(client, "hana", "old-password").status_code == 303
    assert client.get("/api/v1/users/me").json()["username"] == "hana"
    assert client.get("/api/v1/users/me", headers=auth(hana_token)).status_code == 200
    reset = client.patch(
        f"/api/v1/users/{hana.id}", json={"password": "new-password"}, headers=auth(admin)
    )
    assert reset.status_code == 200
    assert client.get("/api/v1/users/me").status_code == 401  # the browser session ended
    assert client.get("/api/v1/users/me", headers=auth(hana_token)).status_code == 401
    assert client.get("/api/v1/users/me", headers=auth(admin)).status_code == 200
    assert form_login(client, "hana", "new-password").status_code == 303


@pytest.mark.parametrize("target", ["https://evil.example/", "//evil.example/", "/\\evil"])
def test_login_never_redirects_off_site(client: TestClient, make_user, target: str) -> None:
    make_user("erin", password="right-password")
    response = form_login(client, "erin", "right-password", target)
    assert response.status_code == 303
    assert response.headers["location"] == "/"


def test_every_response_carries_the_security_headers(client: TestClient, make_user) -> None:
    """nosniff, no framing and the CSP: on a page, the API, an error, a static file."""
    _, token = make_user("headers")
    answers = [
        client.get("/login"),
        client.get("/api/v1/health"),
        client.get("/api/v1/frames/999999", headers=auth(token)),
        client.get("/api/v1/jobs", headers=auth(token)),
        client.get("/static/css/app.css"),
    ]
    assert [a.status_code for a in answers] == [200, 200, 404, 200, 200]
    for answer in answers:
        assert answer.headers["x-content-type-options"] == "nosniff"
        assert answer.headers["x-frame-options"] == "DENY"
        policy = answer.headers["content-security-policy"]
        assert "frame-ancestors 'none'" in policy and "script-src 'self'" in policy
        assert "unsafe-inline" not in policy


def test_a_script_gets_a_token_with_its_password(client: TestClient, make_user) -> None:
    """POST /tokens with username and password (no token yet): 201 with a working token; a
    wrong password is 401 and counts towards the lockout (429 with Retry-After)."""
    make_user("ivan", password="right-password")
    made = client.post(
        "/api/v1/tokens",
        json={"username": "ivan", "password": "right-password", "name": "robot cell 3"},
    )
    assert made.status_code == 201, made.text
    token = made.json()["token"]
    assert made.json()["name"] == "robot cell 3"
    assert client.get("/api/v1/users/me", headers=auth(token)).json()["username"] == "ivan"
    limit = client.app.state.settings.login_max_failures  # type: ignore[attr-defined]
    for _ in range(limit):
        wrong = client.post("/api/v1/tokens", json={"username": "ivan", "password": "nope-nope"})
        assert wrong.status_code == 401 and wrong.json()["detail"] == "Wrong user name or password."
    locked = client.post("/api/v1/tokens", json={"username": "ivan", "password": "right-password"})
    assert locked.status_code == 429 and int(locked.headers["retry-after"]) > 0
    assert client.post("/api/v1/tokens", json={}).status_code == 401
    # With a token and no credentials the caller gets one for themself.
    mine = client.post("/api/v1/tokens", json={"name": "second"}, headers=auth(token))
    assert mine.status_code == 201
    assert client.get("/api/v1/users/me", headers=auth(mine.json()["token"])).status_code == 200


def test_the_first_admins_made_password_is_hashed_cheaply_until_it_is_first_used(
    client: TestClient, session_factory, settings, hash_checks: list[str]
) -> None:
    """A fresh instance's admin password (made here from 16 random bytes) is stored with cheap
    Argon2id parameters, so a first start does not wait for the standard hash; a wrong password
    against it (or against a hash that does not parse) still costs a standard check, the first
    right one re-hashes it with the standard parameters, and a password a person chooses always
    gets them."""

    def stored(name: str) -> str:
        with session_factory() as session:
            return session.scalar(sa.select(User.password_hash).where(User.username == name))

    def kind(password_hash: str) -> str:
        parameters = security.hash_parameters(password_hash)
        names = [(security.STANDARD, "standard"), (security.MADE, "made"), (None, "malformed")]
        return next((name for known, name in names if parameters == known), "other")

    with session_factory() as session:
        password = ensure_initial_admin(session, settings.home).read_text().strip()
        session.add(User(username="broken", password_hash="!", role=Role.annotator))
        session.commit()
    made = stored("admin")
    assert len(password) >= 22 and made.startswith("$argon2id$") and kind(made) == "made"

    checks = hash_checks

    def token_for(name: str, given: str) -> httpx.Response:
        checks.clear()
        return client.post("/api/v1/tokens", json={"username": name, "password": given})

    assert token_for("admin", "not-the-password").status_code == 401
    assert [kind(h) for h in checks] == ["made", "standard"]  # and a standard decoy
    assert stored("admin") == made
    answer = token_for("admin", password)
    assert answer.status_code == 201
    assert [kind(h) for h in checks] == ["made"]
    now = stored("admin")
    assert kind(now) == "standard" and PasswordHasher().verify(now, password)
    assert token_for("admin", password).status_code == 201  # one standard check from now on
    assert [kind(h) for h in checks] == ["standard"]
    for name in ("admin", "nobody"):  # a wrong password, an unknown name: one standard check
        assert token_for(name, "not-the-password").status_code == 401
        assert [kind(h) for h in checks] == ["standard"], name
    assert token_for("broken", "not-the-password").status_code == 401
    assert [kind(h) for h in checks] == ["malformed", "standard"]

    added = client.post(
        "/api/v1/users",
        json={"username": "chosen", "password": "a person's choice"},
        headers=auth(answer.json()["token"]),
    )
    assert added.status_code == 201, added.text
    assert kind(stored("chosen")) == "standard"


def test_a_password_changed_while_the_made_one_is_re_hashed_stays_changed(
    client: TestClient, session_factory, settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The first right use of a made password re-hashes it; a new password that another
    request stores meanwhile (between the check and the re-hash's commit) is not overwritten
    with the old one's hash."""
    with session_factory() as session:
        password = ensure_initial_admin(session, settings.home).read_text().strip()
    rehash = security.hash_password

    def changed_meanwhile(given: str) -> str:
        with session_factory() as other:
            admin = other.scalar(sa.select(User).where(User.username == "admin"))
            admin.password_hash = rehash("changed meanwhile")
            other.commit()
        return rehash(given)

    monkeypatch.setattr(security, "hash_password", changed_meanwhile)
    answer = client.post("/api/v1/tokens", json={"username": "admin", "password": password})
    assert answer.status_code == 201, answer.text
    monkeypatch.setattr(security, "hash_password", rehash)
    with session_factory() as session:
        now = session.scalar(sa.select(User.password_hash).where(User.username == "admin"))
    assert PasswordHasher().verify(now, "changed meanwhile")
    assert (
        client.post("/api/v1/tokens", json={"username": "admin", "password": password}).status_code
        == 401
    )


def test_reactivating_a_user_does_not_revive_their_old_tokens(
    client: TestClient, make_user
) -> None:
    """Tokens issued before a deactivation stay dead: the deactivation revokes them (they were
    only refused while the user was inactive, and worked again after the reactivation)."""
    _, admin = make_user("boss", Role.admin)
    user, token = make_user("returner", password="right-password")
    url = f"/api/v1/users/{user.id}"
    assert client.patch(url, json={"is_active": False}, headers=auth(admin)).status_code == 200
    assert client.patch(url, json={"is_active": True}, headers=auth(admin)).status_code == 200
    assert client.get("/api/v1/users/me", headers=auth(token)).status_code == 401
    fresh = client.post(
        "/api/v1/tokens", json={"username": "returner", "password": "right-password"}
    )
    assert fresh.status_code == 201  # a new token, issued after the reactivation, works
    assert client.get("/api/v1/users/me", headers=auth(fresh.json()["token"])).status_code == 200
