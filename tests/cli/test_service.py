"""The `weldpool` command: users, tokens, migrate, weights, and one-line errors with exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from alembic.script import ScriptDirectory
from click.testing import CliRunner
from fastapi.testclient import TestClient

from app.cli import main
from app.core.config import Settings, get_settings
from app.core.db import MIGRATIONS_DIR
from app.main import create_app
from tests.helpers import auth, make_settings, run_cli


def run(
    settings: Settings, *args: str, stdin: str = "", **env: str
) -> subprocess.CompletedProcess[str]:
    home = {"WELDPOOL_HOME": str(settings.home)}
    database = {"WELDPOOL_DATABASE_URL": settings.resolved_database_url}
    return run_cli(*args, env={**home, **database, **env}, stdin=stdin)


@pytest.fixture
def cli_settings(tmp_path: Path, database_url: str) -> Settings:
    return make_settings(tmp_path / "home", database_url=database_url)


def test_console_script_is_installed() -> None:
    script = Path(sys.executable).parent / "weldpool"
    assert script.exists(), "pip install -e . should install the `weldpool` command"
    result = subprocess.run([str(script), "--help"], capture_output=True, text=True)
    assert result.returncode == 0
    for command in ("serve", "worker", "migrate", "user", "token", "weights"):
        assert command in result.stdout


def test_user_add_token_and_api_access(cli_settings: Settings) -> None:
    assert run(cli_settings, "migrate").returncode == 0
    added = run(
        cli_settings,
        "user",
        "add",
        "welder",
        "--role",
        "reviewer",
        "--password-stdin",
        stdin="a good password\n",
    )
    assert added.returncode == 0, added.stderr
    token = run(cli_settings, "token", "welder")
    assert token.returncode == 0
    text = token.stdout.strip()
    assert token.stdout == text + "\n" and text.startswith("wp_")  # stdout: the token alone

    with TestClient(create_app(cli_settings)) as client:
        me = client.get("/api/v1/users/me", headers=auth(text)).json()
        assert me == me | {"username": "welder", "role": "reviewer"}

    listed = run(cli_settings, "tokens", "list", "welder")
    token_id = listed.stdout.split("\t")[0]
    assert run(cli_settings, "tokens", "revoke", token_id).returncode == 0
    with TestClient(create_app(cli_settings)) as client:
        assert client.get("/api/v1/users/me", headers=auth(text)).status_code == 401


def test_errors_are_one_line_with_exit_status_2(cli_settings: Settings, tmp_path: Path) -> None:
    unmigrated = run(cli_settings, "token", "nobody")
    assert unmigrated.returncode == 2
    head = ScriptDirectory(str(MIGRATIONS_DIR)).get_current_head()
    assert unmigrated.stderr.strip().splitlines() == [
        f"weldpool: The database schema is at revision none, not {head}; "
        "run `weldpool migrate` first."
    ]
    run(cli_settings, "migrate")
    unknown = run(cli_settings, "token", "nobody")
    assert unknown.returncode == 2
    assert len(unknown.stderr.strip().splitlines()) == 1
    assert "There is no user named 'nobody'" in unknown.stderr

    short = run(
        cli_settings, "user", "add", "x", "--role", "admin", "--password-stdin", stdin="short\n"
    )
    assert short.returncode == 2
    assert short.stderr.strip() == "weldpool: The password must have at least 8 characters."

    bad_role = run(cli_settings, "user", "add", "x", "--role", "boss", "--password-stdin")
    assert bad_role.returncode == 2

    bad_setting = run(cli_settings, "migrate", WELDPOOL_QUEUE_URL="amqp://nope")
    assert bad_setting.returncode == 2
    assert bad_setting.stderr.startswith("weldpool: Bad setting WELDPOOL_QUEUE_URL")
    assert "Traceback" not in bad_setting.stderr


def test_unreachable_database_is_one_line(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, database_url="postgresql+psycopg://nobody@127.0.0.1:1/x")
    result = run(settings, "migrate")
    assert result.returncode == 2
    assert result.stderr.startswith("weldpool: The database is unreachable")
    assert "Traceback" not in result.stderr


def test_weights_status_names_the_variable_to_set(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    result = run(settings, "weights", "status", HF_HUB_OFFLINE="1", HF_HOME=str(tmp_path / "hf"))
    assert result.returncode == 2
    assert "set WELDPOOL_DINO to a local directory" in result.stderr
    fetched = run(settings, "weights", "fetch", HF_HUB_OFFLINE="1", HF_HOME=str(tmp_path / "hf"))
    assert fetched.returncode == 2
    assert fetched.stderr.count("\n") == 1 and "WELDPOOL_DINO" in fetched.stderr
    assert "Traceback" not in fetched.stderr


def test_demo_on_a_fresh_home_needs_no_migrate_and_says_how_to_log_in(
    cli_settings: Settings,
) -> None:
    """`weldpool demo` first, on a home that has never been served: it migrates, creates the
    admin, fills a run, and prints where the password is; that password logs in."""
    import re

    result = run(cli_settings, "demo", "--frames", "4")
    assert result.returncode == 0, result.stderr
    hint = re.search(r"log in at \S+ as admin with the password in (\S+)", result.stderr)
    assert hint, result.stderr
    password = Path(hint.group(1)).read_text().strip()
    assert "weldpool serve" in result.stderr
    with TestClient(create_app(cli_settings)) as client:
        page = client.get("/login")
        csrf = re.search(r'name="csrf_token" value="([^"]+)"', page.text).group(1)  # type: ignore[union-attr]
        login = client.post(
            "/login",
            data={"username": "admin", "password": password, "csrf_token": csrf, "next": "/"},
            follow_redirects=False,
        )
        assert login.status_code == 303
        sequences = client.get("/api/v1/sequences").json()
        assert sequences[0]["name"].startswith("demo weld run") and sequences[0]["frame_count"] == 4
        held_out = client.get("/api/v1/frames", params={"split": "validation"}).json()["items"]
        assert held_out  # with masks, so the gate can measure a student on them
        assert all(f["status"] == "accepted" for f in held_out)  # split: by its keypoints
    again = run(cli_settings, "demo", "--frames", "4")  # a second demo: users exist already
    assert again.returncode == 0 and "with your account" in again.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a thread's nice is Linux's")
def test_a_first_start_prepares_the_instance_below_the_serving_thread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The migration and the new admin's Argon2 hash run beside the imports at a job's priority
    (the hash's own threads inherit it); the thread that goes on to serve keeps the process's."""
    import uvicorn

    from app.cli import service

    seen: dict[str, int] = {}
    prepare = service.prepare_instance

    def nice() -> int:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    def recording(settings: Settings) -> Path | None:
        seen["prepare"] = nice()
        return prepare(settings)

    monkeypatch.setattr(service, "prepare_instance", recording)
    monkeypatch.setattr(uvicorn, "run", lambda *args, **kwargs: seen.setdefault("serve", nice()))
    get_settings.cache_clear()
    monkeypatch.setenv("WELDPOOL_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("WELDPOOL_DATABASE_URL", raising=False)
    try:
        result = CliRunner().invoke(main, ["serve", "--no-worker"])
    finally:
        get_settings.cache_clear()
    assert result.exit_code == 0, result.output
    base = nice()
    assert seen == {"prepare": min(19, base + Settings().batch_nice), "serve": base}
    assert "created user 'admin'" in result.output


def test_a_worker_that_could_run_nothing_refuses_to_start(tmp_path: Path) -> None:
    """`weldpool worker` checks what it can run: a model-lane worker with a device this machine
    lacks refuses to start in one sentence (it started, looked alive and failed every job);
    lanes it does not know are refused too."""
    settings = make_settings(tmp_path / "home")
    assert run(settings, "migrate").returncode == 0
    no_gpu = run(settings, "worker", "--lanes", "model", WELDPOOL_DEVICE="cuda:7")
    assert no_gpu.returncode == 2
    assert no_gpu.stderr.strip().splitlines()[-1] == (
        "weldpool: This worker can run no job of its lanes: WELDPOOL_DEVICE='cuda:7' but no such "
        "CUDA device is present; use cpu or auto."
    )
    unknown = run(settings, "worker", "--lanes", "fast")
    assert unknown.returncode == 2
    assert "--lanes takes quick, model or both, not 'fast'." in unknown.stderr
