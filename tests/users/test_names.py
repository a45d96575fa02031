"""A user name is one user in any case: 'Alice' cannot be added beside 'alice', and either
spelling logs in; a database that already holds two such names still migrates."""

from __future__ import annotations

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.db import create_db_engine, head_revision, schema_revision
from app.core.errors import ConflictError
from app.core.models import Role, User
from app.core.schema import migrate
from app.core.security import hash_password
from app.users.service import create_user
from tests.helpers import auth


def test_a_name_differing_only_by_case_is_taken(client: TestClient, make_user) -> None:
    _, admin = make_user("boss", Role.admin)
    make_user("alice", password="right-password")
    twin = client.post(
        "/api/v1/users",
        json={"username": "Alice", "password": "long enough 1", "role": "annotator"},
        headers=auth(admin),
    )
    assert twin.status_code == 409, twin.text
    assert twin.json()["detail"] == "There is already a user named 'alice'."
    names = [u["username"] for u in client.get("/api/v1/users", headers=auth(admin)).json()]
    assert names == ["alice", "boss"]


def test_a_user_logs_in_by_their_name_in_any_case(client: TestClient, make_user) -> None:
    make_user("Alice", password="right-password")
    for spelling in ("Alice", "alice", "ALICE"):
        made = client.post(
            "/api/v1/tokens", json={"username": spelling, "password": "right-password"}
        )
        assert made.status_code == 201, (spelling, made.text)
        me = client.get("/api/v1/users/me", headers=auth(made.json()["token"])).json()
        assert me["username"] == "Alice"


def test_a_database_holding_names_that_differ_only_by_case_still_migrates(
    database_url: str,
) -> None:
    """Two such names from before stay two users, each logging in by its exact name (another
    spelling matches neither: 401); the index that keeps names unique in any case waits until
    one is renamed, and the service refuses a third."""
    from app.core.security import authenticate

    engine = create_db_engine(database_url)
    migrate(engine, "0018")
    with engine.begin() as connection:
        for name in ("alice", "Alice"):
            connection.execute(
                sa.insert(User.__table__).values(
                    username=name, password_hash=hash_password(f"{name} secret"), role="annotator"
                )
            )
    migrate(engine)
    assert schema_revision(engine)[0] == head_revision()
    with sa.orm.Session(engine) as session:
        assert authenticate(session, "alice", "alice secret").username == "alice"  # type: ignore[union-attr]
        assert authenticate(session, "Alice", "Alice secret").username == "Alice"  # type: ignore[union-attr]
        assert authenticate(session, "ALICE", "alice secret") is None
        with pytest.raises(ConflictError, match="already a user named"):
            create_user(session, "ALICE", "long enough 1", Role.annotator)
    engine.dispose()


def test_a_fresh_database_keeps_names_unique_in_any_case(database_url: str) -> None:
    engine = create_db_engine(database_url)
    migrate(engine)
    with engine.begin() as connection:
        connection.execute(
            sa.insert(User.__table__).values(username="bob", password_hash="x", role="annotator")
        )
    try:
        with engine.begin() as connection:
            connection.execute(
                sa.insert(User.__table__).values(
                    username="BOB", password_hash="x", role="annotator"
                )
            )
    except sa.exc.IntegrityError:
        pass
    else:
        raise AssertionError("the database took 'BOB' beside 'bob'")
    engine.dispose()
