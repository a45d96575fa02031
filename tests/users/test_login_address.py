"""The login lockout counts the connection's address: X-Forwarded-For is believed only from the
proxies in WELDPOOL_TRUSTED_PROXIES (none by default), and every way a login can fail costs
the same one password check."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError

from app.core.config import Settings
from app.core.models import Role
from tests.helpers import auth, wait_for


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextmanager
def _serve(home: Path, **settings: str) -> Iterator[str]:
    """`weldpool serve` on a fresh home with these WELDPOOL_ settings; yields its base URL."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("WELDPOOL_")}
    env.update(WELDPOOL_HOME=str(home), HF_HUB_OFFLINE="1", WELDPOOL_LOGIN_MAX_FAILURES="1")
    env.update({f"WELDPOOL_{name.upper()}": value for name, value in settings.items()})
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--port", str(port), "--no-worker"],
        env=env,
        cwd=home.parent,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    base = f"http://127.0.0.1:{port}"
    try:

        def up() -> bool:
            try:
                return httpx.get(f"{base}/api/v1/health", timeout=2).status_code in (200, 503)
            except httpx.HTTPError:
                return False

        assert wait_for(up, timeout=60, interval=0.2)
        yield base
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=60)


def _spray(base: str, count: int, forwarded_for: list[str], names: str = "guess") -> list[int]:
    """Wrong passwords for a new name each time (the per-name limit never bites), each with
    the next X-Forwarded-For address; the statuses."""
    return [
        httpx.post(
            f"{base}/api/v1/tokens",
            json={"username": f"{names}{i}", "password": "wrong-password"},
            headers={"X-Forwarded-For": forwarded_for[i % len(forwarded_for)]},
            timeout=30,
        ).status_code
        for i in range(count)
    ]


@pytest.mark.slow
def test_a_rotating_forwarded_for_does_not_escape_the_address_lockout(tmp_path: Path) -> None:
    """By default no proxy is trusted: a sprayer on 127.0.0.1 that rotates X-Forwarded-For is
    counted as 127.0.0.1, and after 4× WELDPOOL_LOGIN_MAX_FAILURES (1) wrong passwords it is
    refused with 429."""
    with _serve(tmp_path / "data") as base:
        statuses = _spray(base, 6, [f"203.0.113.{i}" for i in range(1, 200)])
    assert statuses == [401, 401, 401, 401, 429, 429]


@pytest.mark.slow
def test_a_trusted_proxys_forwarded_for_is_honoured(tmp_path: Path) -> None:
    """With WELDPOOL_TRUSTED_PROXIES naming 127.0.0.1 the header names the client: one client
    behind the proxy is locked out, another behind the same proxy still gets an answer."""
    with _serve(tmp_path / "data", trusted_proxies="127.0.0.1") as base:
        locked = _spray(base, 5, ["203.0.113.7"])
        other = _spray(base, 1, ["198.51.100.9"], names="another")
    assert locked == [401, 401, 401, 401, 429]
    assert other == [401]


def test_trusted_proxies_are_addresses_or_networks() -> None:
    settings = Settings(_env_file=None, trusted_proxies=" 10.0.0.5, 10.1.0.0/16 ,::1")  # type: ignore[call-arg]
    assert settings.trusted_proxy_list == ["10.0.0.5", "10.1.0.0/16", "::1"]
    loose = Settings(_env_file=None, trusted_proxies="10.0.0.5/24")  # type: ignore[call-arg]
    assert loose.trusted_proxy_list == ["10.0.0.0/24"]  # as uvicorn reads a network
    assert Settings(_env_file=None).trusted_proxy_list == []  # type: ignore[call-arg]
    with pytest.raises(ValidationError, match=r"WELDPOOL_TRUSTED_PROXIES: 'proxy\.local'"):
        Settings(_env_file=None, trusted_proxies="10.0.0.5,proxy.local")  # type: ignore[call-arg]


def test_every_failed_login_checks_one_password_hash(
    client: TestClient, make_user, hash_checks: list[str]
) -> None:
    """An active user (wrong and right password), a deactivated one and an unknown name each
    cost exactly one hash check, so the time of the answer tells none of them apart."""
    _, admin = make_user("boss", Role.admin)
    make_user("active", password="right-password")
    leaver, _ = make_user("leaver", password="right-password")
    assert client.patch(
        f"/api/v1/users/{leaver.id}", json={"is_active": False}, headers=auth(admin)
    ).is_success
    checks = hash_checks
    for username, password, status in (
        ("active", "wrong-password", 401),
        ("leaver", "right-password", 401),
        ("nobody", "right-password", 401),
        ("active", "right-password", 201),
    ):
        checks.clear()
        answer = client.post("/api/v1/tokens", json={"username": username, "password": password})
        assert answer.status_code == status, (username, answer.text)
        assert len(checks) == 1, username
        assert checks[0].startswith("$argon2id$"), username  # a real check, not a shortcut
