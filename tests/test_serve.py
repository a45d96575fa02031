"""The README's first command: `weldpool serve` on embedded defaults, as a user runs it."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from tests.helpers import fresh_python, wait_for

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_serve_migrates_serves_and_runs_jobs(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("WELDPOOL_")}
    env.update(WELDPOOL_HOME=str(tmp_path / "data"), HF_HUB_OFFLINE="1")
    weldpool = [sys.executable, "-m", "app"]
    port = _free_port()
    log = open(tmp_path / "serve.log", "w")  # noqa: SIM115
    server = subprocess.Popen(
        [*weldpool, "serve", "--port", str(port)],
        env=env,
        cwd=tmp_path,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"
    try:

        def health() -> dict | None:
            try:
                return httpx.get(f"{base}/api/v1/health", timeout=2).json()
            except httpx.HTTPError:
                return None

        body = wait_for(health, timeout=60, interval=0.2)
        assert body["status"] == "degraded"  # no teacher weights on this machine, said so
        assert body["warnings"][0].startswith("The teacher cannot run")
        assert body["database"] == body["database"] | {"backend": "sqlite", "status": "ok"}
        assert body["queue"] == body["queue"] | {"backend": "sqlite", "status": "ok"}
        assert body["teacher"]["dino"]["available"] is False  # no weights on this machine
        assert (tmp_path / "data" / "weldpool.sqlite3").exists()
        assert "Log in" in httpx.get(f"{base}/login").text

        # A fresh instance has an admin whose password is in a file only its owner reads.
        password_file = tmp_path / "data" / "initial-admin-password"
        assert password_file.stat().st_mode & 0o777 == 0o600
        password = password_file.read_text().strip()
        browser = httpx.Client(base_url=base, follow_redirects=True)
        csrf = browser.get("/login").text.split('name="csrf_token" value="')[1].split('"')[0]
        login = browser.post(
            "/login", data={"username": "admin", "password": password, "csrf_token": csrf}
        )
        assert 'data-testid="current-user">admin<' in login.text
        token = subprocess.run(
            [*weldpool, "token", "admin"], env=env, capture_output=True, text=True, check=True
        ).stdout.strip()
        headers = {"Authorization": f"Bearer {token}"}
        job_id = httpx.post(
            f"{base}/api/v1/jobs/diagnostic", json={"seconds": 0.2}, headers=headers
        ).json()["job_id"]
        job = wait_for(
            lambda: (
                (j := httpx.get(f"{base}/api/v1/jobs/{job_id}", headers=headers).json())["status"]
                in ("succeeded", "failed")
                and j
            ),
            timeout=30,
        )
        assert job["status"] == "succeeded"
        assert job["result"]["pid"] == server.pid  # the embedded worker ran it
        docs = httpx.get(f"{base}/docs", headers=headers)
        assert docs.status_code == 200 and "swagger" in docs.text.lower()
    finally:
        server.terminate()
        server.wait(timeout=30)
        log.close()
    # uvicorn shuts down cleanly, then re-raises SIGTERM so the exit status tells why it ended.
    assert server.returncode in (0, -signal.SIGTERM)
    assert "Application shutdown complete." in (tmp_path / "serve.log").read_text()


def test_serve_binds_loopback_by_default() -> None:
    from click.testing import CliRunner

    from app.cli import main

    help_text = CliRunner().invoke(main, ["serve", "--help"]).output
    assert "default: 127.0.0.1" in help_text


def test_a_web_process_without_worker_loads_no_ml_stack(tmp_path: Path) -> None:
    """`serve --no-worker` answers pages and lists without torch, scikit-learn or SciPy: their
    shared libraries are not even mapped into the process (the worker loads them on a job)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("WELDPOOL_")}
    env.update(WELDPOOL_HOME=str(tmp_path / "data"), HF_HUB_OFFLINE="1")
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--port", str(port), "--no-worker"],
        env=env,
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        assert wait_for(lambda: _healthy(base), timeout=60)
        for path in ("/login", "/api/v1/health", "/static/js/api.js"):
            assert httpx.get(base + path, timeout=10).status_code == 200
        assert httpx.get(f"{base}/api/v1/frames", timeout=10).status_code == 401
        maps = Path(f"/proc/{server.pid}/maps").read_text()
        for library in ("/torch/lib/", "/sklearn/", "/scipy/", "/onnxruntime/"):
            assert library not in maps, f"the web process loaded {library}"
        assert "/pydantic_core/" in maps  # the check sees the libraries it does load
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=60)


def _healthy(base: str) -> bool:
    try:
        return httpx.get(f"{base}/api/v1/health", timeout=2).status_code in (200, 503)
    except httpx.HTTPError:
        return False


def test_a_web_process_answers_health_without_huey_or_the_hub_client(tmp_path: Path) -> None:
    """`serve --no-worker` on SQLite counts its queue and finds the teacher's weights without
    importing Huey (with redis and psycopg), huggingface_hub's download client, the pages'
    Jinja, rich (structlog's traceback drawing) or the numerical libraries (NumPy, OpenCV,
    Pillow's Image, PyYAML: `weldpool_core.lazy`): start-up cost they would add to every
    restart. Huey comes with the first job, Jinja with the first page."""
    script = """
import sys
from fastapi.testclient import TestClient
from app.core.db import create_db_engine
from app.core.schema import migrate
from app.main import create_app
from tests.helpers import make_settings
settings = make_settings(__import__("pathlib").Path(sys.argv[1]))
migrate(create_db_engine(settings.resolved_database_url))
with TestClient(create_app(settings)) as client:
    body = client.get("/api/v1/health").json()
    assert body["queue"]["pending"] == 0, body
    print(sorted(m for m in ("huey", "redis", "huggingface_hub.file_download", "jinja2", "rich",
                             "numpy", "cv2", "PIL.Image", "yaml") if m in sys.modules))
    assert "<form" in client.get("/login").text
    print("jinja2" in sys.modules)
create_app(settings).state.queue.enqueue(1, "diagnostic")
print("huey" in sys.modules)
"""
    env = {k: v for k, v in os.environ.items() if not k.startswith("WELDPOOL_")}
    env["HF_HUB_OFFLINE"] = "1"
    out = fresh_python(script, str(tmp_path / "home"), env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:3] == ["[]", "True", "True"]


def test_logs_keep_tracebacks_without_rich() -> None:
    """A fresh process hides rich from structlog (start-up), and an exception logged in either
    format still carries its whole traceback as plain text."""
    script = """
import sys
import app
import structlog
from app.core.logs import configure_logging
print("rich" in sys.modules)
log = structlog.get_logger("check")
for fmt in ("console", "json"):
    configure_logging(fmt=fmt)
    try:
        {}["missing key"]
    except KeyError:
        log.exception("failed", frame=7)
"""
    out = fresh_python(script)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    assert "failed" in out.stderr and "frame=7" in out.stderr
    assert out.stderr.count("Traceback (most recent call last)") == 2
    assert out.stderr.count("KeyError: 'missing key'") == 2
    assert json.loads(out.stderr.strip().splitlines()[-1])["exception"].endswith(
        "KeyError: 'missing key'"
    )
