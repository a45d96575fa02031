"""Fixtures of the user and login tests."""

from __future__ import annotations

import pytest

from app.core import security


@pytest.fixture
def hash_checks(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every stored hash a password is checked against from now on, in order (the checks still
    run: the list only records them)."""
    checks: list[str] = []
    verify = security.verify_password

    def counted(password_hash: str, password: str) -> bool:
        checks.append(password_hash)
        return verify(password_hash, password)

    monkeypatch.setattr(security, "verify_password", counted)
    return checks
