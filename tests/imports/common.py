"""Labelled frames exported by one instance, to import into another."""

from __future__ import annotations

import base64
import io
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Role, User
from app.core.security import hash_password, issue_token
from app.main import create_app
from tests.helpers import auth, corrected_label, image_bytes, make_settings, wait_for_job
from weldpool_core.io import decode_mask_png

W, H = 96, 64
PROCESS = {"wire_feed_m_min": 6.5, "voltage_v": 21.0, "current_a": 160.0, "joint_type": "bead"}


def ring() -> np.ndarray:
    """A pool with a hole: what an outline without holes would lose."""
    mask = np.zeros((H, W), bool)
    mask[10:50, 20:70] = True
    mask[22:38, 36:54] = False
    return mask


def two_blobs() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[5:25, 5:30] = True
    mask[35:60, 50:90] = True
    return mask


def blob() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    yy, xx = np.mgrid[:H, :W]
    mask[(xx - 48) ** 2 / 30**2 + (yy - 32) ** 2 / 18**2 <= 1] = True
    return mask


MASKS = [ring(), two_blobs(), blob()]
KEYPOINTS = [[30.0, 20.0], [60.0, 20.0], [60.0, 40.0], [30.0, 40.0]]
VALIDATION = [[40.5, 25.0], [55.0, 30.25]]


@dataclass
class Exported:
    """What the first instance stored: its frames' images, masks and keypoints by name."""

    names: list[str]
    images: dict[str, bytes]
    masks: dict[str, np.ndarray]
    keypoints: dict[str, list[list[float]]]
    validation: dict[str, list[list[float]]]
    archive: dict[str, bytes]  # format → exported zip


def token_for(session_factory, name: str, role: Role = Role.reviewer) -> tuple[User, str]:
    with session_factory() as session:
        user = User(username=name, password_hash=hash_password("correct horse"), role=role)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user, "test")
        session.commit()
        return user, token


def export_labels(home: Path, formats: list[str]) -> Exported:
    """A SQLite instance under ``home`` with three labelled frames of run "run-a" (a mask with
    a hole, two regions, keypoints given on one, validation keypoints on another), exported."""
    from app.core.db import create_db_engine, create_session_factory
    from app.core.schema import migrate

    settings = make_settings(home, database_url=f"sqlite:///{home / 'source.sqlite3'}")
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    _, token = token_for(create_session_factory(engine), "exporter")
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        run = client.post(
            "/api/v1/sequences", json={"name": "run-a", **PROCESS}, headers=auth(token)
        ).json()
        names = [f"weld_{i}.png" for i in range(3)]
        images = {n: image_bytes(W, H, seed=700 + i) for i, n in enumerate(names)}
        files = [("files", (n, images[n], "image/png")) for n in names]
        stored = client.post(
            "/api/v1/frames", data={"sequence_id": run["id"]}, files=files, headers=auth(token)
        ).json()["stored"]
        ids = {f["original_name"]: f["id"] for f in stored}
        keypoints: dict[str, list[list[float]]] = {}
        for name, mask in zip(names, MASKS, strict=True):
            body = corrected_label(mask)
            if name == names[2]:
                body["keypoints"] = KEYPOINTS
            saved = client.put(f"/api/v1/frames/{ids[name]}/label", json=body, headers=auth(token))
            assert saved.status_code == 200, saved.text
            keypoints[name] = saved.json()["keypoints"]
        manual = client.put(
            f"/api/v1/frames/{ids[names[1]]}/validation-keypoints",
            json={"keypoints": VALIDATION},
            headers=auth(token),
        )
        assert manual.status_code == 200, manual.text
        archive = {}
        for fmt in formats:
            response = client.get("/api/v1/export", params={"format": fmt}, headers=auth(token))
            assert response.status_code == 200, response.text
            archive[fmt] = response.content
    engine.dispose()
    return Exported(
        names,
        images,
        dict(zip(names, MASKS, strict=True)),
        keypoints,
        {names[1]: VALIDATION},
        archive,
    )


def start_import(
    client: TestClient, token: str, data: bytes, fmt: str, name: str = "labels.zip", **fields
) -> dict:
    form = {
        "format": fmt,
        **{k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in fields.items()},
    }
    response = client.post(
        "/api/v1/labels/import",
        data=form,
        files={"file": (name, data, "application/octet-stream")},
        headers=auth(token),
    )
    assert response.status_code == 202, response.text
    job = wait_for_job(client, response.json()["job_id"], token, timeout=60)
    assert job["status"] == "succeeded", job["error"]
    return job


def stored_labels(client: TestClient, token: str) -> Iterator[tuple[dict, dict | None]]:
    """Every frame here (by original name) with its label, if any."""
    frames = client.get("/api/v1/frames", params={"limit": 200}, headers=auth(token)).json()
    for frame in frames["items"]:
        label = client.get(f"/api/v1/frames/{frame['id']}/label", headers=auth(token))
        yield frame, (label.json() if label.status_code == 200 else None)


def label_mask(label: dict) -> np.ndarray:
    return decode_mask_png(base64.b64decode(label["mask_png"]))


def zipped(files: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def masks_archive(count: int, seed: int = 300) -> bytes:
    """A zip in the masks layout: ``count`` frames, each with a pool mask a little unlike the
    others (``count`` over 64 makes several batches)."""
    from tests.helpers import image_bytes
    from weldpool_core.io import encode_mask_png

    files = {}
    for i in range(count):
        mask = np.zeros((H, W), bool)
        mask[5 + i % 10 : 40, 10:60] = True
        files[f"images/{i}.png"] = image_bytes(W, H, seed=seed + i)
        files[f"masks/{i}.png"] = encode_mask_png(mask)
    return zipped(files)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def same_points(a: list[list[float]], b: list[list[float]]) -> bool:
    """Equal keypoints, to the 0.01 px a format writes them with."""
    return np.asarray(a).shape == np.asarray(b).shape and bool(
        np.allclose(np.asarray(a), np.asarray(b), atol=0.005)
    )
