"""A real `weldpool serve` on a free port, with the tiny random-weight teacher, for the browser
tests and bench/ui.py; and the Chromium that Playwright drives."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role
from app.core.security import issue_token
from app.users.service import create_user
from tests.helpers import wait_for
from tests.models import save_tiny_teacher

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
PASSWORD = "weld-pool-2024"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def missing_browser() -> str | None:
    """Why the browser tests cannot run here, or None."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "Playwright is not installed: pip install -e '.[test]'."
    if not CHROMIUM.exists():
        return f"Chromium is missing at {CHROMIUM}: apt-get install -y chromium (.ci/run does)."
    return None


def launch_chromium(playwright: Any) -> Any:
    """Debian's Chromium, headless (Playwright cannot download browsers here)."""
    return playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)


@dataclass
class LiveServer:
    """`weldpool serve` in a subprocess, on SQLite in its own home, with an embedded worker."""

    home: Path
    with_weights: bool = True  # False: the teacher's weights point nowhere (a new install)
    port: int = field(default_factory=free_port)
    process: subprocess.Popen[bytes] | None = None
    tokens: dict[str, str] = field(default_factory=dict)
    env: dict[str, str] = field(default_factory=dict)  # more settings (WELDPOOL_…) for this one

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> LiveServer:
        self.home.mkdir(parents=True, exist_ok=True)
        teacher = save_tiny_teacher(self.home.parent / "teacher-weights")
        env = {k: v for k, v in os.environ.items() if not k.startswith("WELDPOOL_")}
        env.update(
            HF_HUB_OFFLINE="1",
            WELDPOOL_HOME=str(self.home),
            WELDPOOL_DINO=str(teacher["dino"] if self.with_weights else self.home / "no-dino"),
            WELDPOOL_SAM2=str(teacher["sam2"] if self.with_weights else self.home / "no-sam2"),
            WELDPOOL_DINO_INPUT_SIZE=str(teacher["dino_input_size"]),
            WELDPOOL_DEVICE=str(teacher["device"]),
            WELDPOOL_RETRAIN_EVERY="0",
            WELDPOOL_WORKERS="2",
            WELDPOOL_JOB_HEARTBEAT_S="0.5",
            WELDPOOL_LOG_LEVEL="WARNING",
        )
        env.update(self.env)
        log = (self.home.parent / "serve.log").open("wb")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "app", "serve", "--port", str(self.port)],
            env=env,
            cwd=self.home.parent,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        log.close()

        def healthy() -> bool:
            if self.process is not None and self.process.poll() is not None:
                raise AssertionError(f"weldpool serve exited: {self.log()[-2000:]}")
            try:
                return httpx.get(f"{self.url}/api/v1/health", timeout=2).status_code == 200
            except httpx.HTTPError:
                return False

        wait_for(healthy, timeout=90, interval=0.2)
        self._add_users()
        return self

    def _add_users(self) -> None:
        engine = create_db_engine(f"sqlite:///{(self.home / 'weldpool.sqlite3').resolve()}")
        try:
            with create_session_factory(engine)() as session:
                for name, role in (
                    ("ada", Role.admin),
                    ("rita", Role.reviewer),
                    ("anna", Role.annotator),
                ):
                    user = create_user(session, name, PASSWORD, role)
                    self.tokens[name] = issue_token(session, user, "browser tests")[1]
                session.commit()
        finally:
            engine.dispose()

    def log(self) -> str:
        path = self.home.parent / "serve.log"
        return path.read_text(errors="replace") if path.exists() else ""

    def api(self, method: str, path: str, user: str = "rita", **kwargs: Any) -> httpx.Response:
        """Call the REST API as ``user`` with a bearer token."""
        headers = {"Authorization": f"Bearer {self.tokens[user]}"}
        return httpx.request(
            method, f"{self.url}/api/v1{path}", headers=headers, timeout=60, **kwargs
        )

    def wait_for_job(self, job_id: int, timeout: float = 120) -> dict[str, Any]:
        def finished() -> dict[str, Any] | None:
            job: dict[str, Any] = self.api("GET", f"/jobs/{job_id}").json()
            return job if job["status"] in ("succeeded", "failed", "cancelled") else None

        result: dict[str, Any] = wait_for(finished, timeout=timeout, interval=0.2)
        return result

    def stop(self) -> None:
        if self.process is None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=10)
        self.process = None
