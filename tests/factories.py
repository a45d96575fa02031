"""The data tests build through the API: images, frames, the teacher's proposals, a browser
session; and frames on a live server. Test modules import these from here (or from
``tests.helpers``, ``tests.pages``), never from one another."""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from fastapi.testclient import TestClient

from tests.helpers import auth, image_bytes, wait_for_job

if TYPE_CHECKING:
    from tests.web.server import LiveServer

# --- images -------------------------------------------------------------------------------------


def numbered(count: int, *, first_seed: int = 0, name: str = "{i}.png") -> list[tuple[str, int]]:
    """``(name, seed)`` for ``count`` images: the ``i``-th named ``name.format(i=i)``, drawn from
    seed ``first_seed + i``."""
    return [(name.format(i=i), first_seed + i) for i in range(count)]


def random_images(
    names_and_seeds: Iterable[tuple[str, int]], *, width: int = 64, height: int = 48
) -> list[tuple[str, bytes]]:
    """PNGs of random grey levels as ``(name, bytes)``, one per ``(name, seed)``: one seed, one
    content (the same seed again is a duplicate to ingest)."""
    return [(name, image_bytes(width, height, seed=seed)) for name, seed in names_and_seeds]


def synthetic_png(seed: int, width: int = 1280, height: int = 800) -> bytes:
    """A realistic weld-pool frame, PNG-encoded."""
    import cv2

    from weldpool_core.synth import SynthParams, synth_frame

    ok, data = cv2.imencode(".png", synth_frame(seed=seed, params=SynthParams(width, height)).image)
    assert ok
    return bytes(data.tobytes())


def synthetic_images(
    names_and_seeds: Iterable[tuple[str, int]], *, width: int = 160, height: int = 100
) -> list[tuple[str, bytes]]:
    """Synthetic weld-pool frames (``weldpool_core.synth``) as ``(name, PNG)``, one per
    ``(name, seed)``."""
    return [(name, synthetic_png(seed, width, height)) for name, seed in names_and_seeds]


# --- frames, proposals, sessions through the API ------------------------------------------------


def upload_frames(
    client: TestClient,
    token: str,
    files: Iterable[tuple[str, bytes]],
    *,
    sequence_id: int | None = None,
) -> list[dict[str, Any]]:
    """Store ``(name, PNG)`` files as frames in one ``POST /frames`` (into a sequence if given);
    the stored frames as the API lists them, in file order."""
    parts = [("files", (name, content, "image/png")) for name, content in files]
    data = {"sequence_id": str(sequence_id)} if sequence_id is not None else {}
    response = client.post("/api/v1/frames", files=parts, data=data, headers=auth(token))
    assert response.status_code == 201, response.text
    stored: list[dict[str, Any]] = response.json()["stored"]
    return stored


def frame_ids(
    client: TestClient,
    token: str,
    files: Iterable[tuple[str, bytes]],
    *,
    sequence_id: int | None = None,
) -> list[int]:
    """``upload_frames``, returning the new frames' ids."""
    return [int(f["id"]) for f in upload_frames(client, token, files, sequence_id=sequence_id)]


def upload_synthetic(client: TestClient, token: str, count: int = 2) -> list[int]:
    """``count`` synthetic 160×100 weld-pool frames (``s0.png``, … from seeds 0, …): their ids."""
    return frame_ids(client, token, synthetic_images(numbered(count, name="s{i}.png")))


def run_teacher(client: TestClient, token: str, frame_ids: list[int]) -> dict[str, Any]:
    """A teacher run on these frames, waited for: the finished job's JSON."""
    response = client.post(
        "/api/v1/teacher/runs", json={"frame_ids": frame_ids}, headers=auth(token)
    )
    assert response.status_code == 202, response.text
    return wait_for_job(client, response.json()["job_id"], token, timeout=120)


def form_login(client: TestClient, username: str, password: str, next_url: str = "/") -> Any:
    """Log in through the login form as a browser does (its CSRF token first); the form's
    answer, not followed."""
    page = client.get("/login", params={"next": next_url})
    csrf = re.search(r'name="csrf_token" value="([^"]+)"', page.text)
    assert csrf, page.text
    return client.post(
        "/login",
        data={
            "username": username,
            "password": password,
            "csrf_token": csrf.group(1),
            "next": next_url,
        },
        follow_redirects=False,
    )


# --- on a live server (the browser tests) -------------------------------------------------------


def add_frame(server: LiveServer, seed: int, *, teacher: bool = True) -> int:
    """Upload a synthetic 1280×800 frame through the API, optionally with its proposal."""
    files = [("files", (f"seed-{seed}.png", synthetic_png(seed), "image/png"))]
    response = server.api("POST", "/frames", files=files)
    assert response.status_code == 201, response.text
    frame_id: int = response.json()["stored"][0]["id"]
    if teacher:
        job = server.api("POST", "/teacher/runs", json={"frame_ids": [frame_id]}).json()
        assert server.wait_for_job(job["job_id"])["status"] == "succeeded"
    return frame_id


def add_version(server: LiveServer, **columns: Any) -> int:
    """A student version row written straight into the live server's SQLite database."""
    from app.core.db import create_db_engine, create_session_factory
    from app.core.models import ModelVersion

    engine = create_db_engine(f"sqlite:///{(server.home / 'weldpool.sqlite3').resolve()}")
    try:
        with create_session_factory(engine)() as session:
            version = ModelVersion(**columns)
            session.add(version)
            session.commit()
            return version.id
    finally:
        engine.dispose()
