"""The app's sequential-cell job on the real WAAM videos, end to end through the API.

What a user does: import the three real videos (every 5th frame), save the 9 hand-drawn masks as
corrected labels, put one clip's three frames in the validation split (manual keypoints, from
Algorithm 1 on the true mask), train a student version on the other two clips' six, then
"Train sequential cell" on it. Prints the seconds of each job and the version's record: the cell
against the per-frame student on the held-out clip's three frames (mask IoU at model
resolution) and on unlabelled stretches of the videos (share of the mask that changes per
frame). One SQLite home in a temporary folder, the embedded worker, the CPU.

    PYTHONPATH=. HF_HUB_OFFLINE=1 .venv/bin/python bench/app_sequential.py [--held mm] [--steps 200]

Measured 2026-11-29 on 2 CPU cores (defaults, seed 0; mask IoU on the held-out clip's 3 frames
per frame → sequential; the change of the mask per frame over 48 unlabelled stretches the cell
never trained on): held out 0mm 0.742 → 0.745, 0.87 → 0.54 %; 2mm 0.839 → 0.838, 0.92 →
0.59 %; mm 0.857 → 0.847, 1.17 → 0.75 %. Student job 267–291 s, the cell's 226–252 s.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from fastapi.testclient import TestClient
from results import recorded

REPO = Path(__file__).resolve().parents[1]
CLIPS = ("0mm", "2mm", "mm")


def shared_data() -> Path:
    return Path(os.environ.get("WELDPOOL_SHARED_DATA") or REPO.parent / "shared" / "data")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--held", choices=CLIPS, default="mm", help="the validation clip")
    parser.add_argument("--steps", type=int, default=None, help="cell steps (default 200)")
    args = parser.parse_args()

    from app.core.config import Settings
    from app.core.db import create_db_engine, create_session_factory
    from app.core.models import Role, User
    from app.core.schema import migrate
    from app.core.security import hash_password, issue_token
    from app.main import create_app
    from tests.helpers import corrected_label
    from weldpool_core.heatmap import heatmap_from_mask

    data = shared_data() / "waam"
    with tempfile.TemporaryDirectory() as root:
        home = Path(root) / "home"
        settings = Settings(_env_file=None, home=home, device="cpu")  # type: ignore[call-arg]
        engine = create_db_engine(settings.resolved_database_url)
        migrate(engine)
        with create_session_factory(engine)() as session:
            user = User(username="bench", password_hash=hash_password("x" * 12), role=Role.admin)
            session.add(user)
            session.flush()
            _, token = issue_token(session, user, "bench")
            session.commit()
        headers = {"Authorization": f"Bearer {token}"}
        with TestClient(create_app(settings, embedded_worker=True)) as client:

            def wait(job_id: int) -> dict:
                while True:
                    job = client.get(f"/api/v1/jobs/{job_id}", headers=headers).json()
                    if job["status"] in ("succeeded", "failed", "cancelled"):
                        return job
                    time.sleep(1.0)

            frame_ids: dict[tuple[str, int], int] = {}
            for clip in CLIPS:
                path = data / "video" / f"compressed_{clip}.mp4"
                with open(path, "rb") as handle:
                    uploaded = client.post(
                        "/api/v1/videos",
                        files={"file": (path.name, handle, "video/mp4")},
                        data={"every_nth": "5"},
                        headers=headers,
                    ).json()
                job = wait(uploaded["job_id"])
                assert job["status"] == "succeeded", job
                items = client.get(
                    "/api/v1/frames",
                    params={"sequence_id": uploaded["video"]["sequence_id"], "limit": 500},
                    headers=headers,
                ).json()["items"]
                frame_ids |= {(clip, f["frame_index"]): f["id"] for f in items}
            for label in sorted((data / "labels").glob("*.png")):
                clip, index = label.stem.removeprefix("compressed_").rsplit("_f", 1)
                frame_id = frame_ids[(clip, int(index))]
                mask = cv2.imread(str(label), cv2.IMREAD_GRAYSCALE) > 0
                saved = client.put(
                    f"/api/v1/frames/{frame_id}/label",
                    json=corrected_label(mask),
                    headers=headers,
                )
                assert saved.status_code == 200, saved.text
                if clip == args.held:
                    points = heatmap_from_mask(mask).keypoints.tolist()
                    placed = client.put(
                        f"/api/v1/frames/{frame_id}/validation-keypoints",
                        json={"keypoints": points},
                        headers=headers,
                    )
                    assert placed.status_code == 200, placed.text
            started = time.perf_counter()
            job = wait(
                client.post("/api/v1/student/train", json={}, headers=headers).json()["job_id"]
            )
            assert job["status"] == "succeeded", job
            student_s = time.perf_counter() - started
            version = client.get("/api/v1/models", headers=headers).json()[0]
            body = {"steps": args.steps} if args.steps else {}
            started = time.perf_counter()
            job = wait(
                client.post(
                    f"/api/v1/models/{version['id']}/sequential", json=body, headers=headers
                ).json()["job_id"]
            )
            cell_s = time.perf_counter() - started
            assert job["status"] == "succeeded", job
            record = client.get(f"/api/v1/models/{version['id']}", headers=headers).json()
    measured = record["sequential"]["measured"]
    print(f"held-out clip {args.held}: student {student_s:.0f} s, cell {cell_s:.0f} s")
    print(f"version mIoU on its validation frames {record['metrics'].get('mIoU', np.nan):.3f}")
    print("| | per frame | sequential |")
    print("|---|---:|---:|")
    print(
        f"| mask IoU, {measured['frames']} held-out frames (model resolution) | "
        f"{measured['per_frame_iou']:.3f} | {measured['sequential_iou']:.3f} |"
    )
    print(
        f"| mask change per frame, {measured['windows']} unlabelled stretches | "
        f"{100 * measured['per_frame_change']:.2f} % | "
        f"{100 * measured['sequential_change']:.2f} % |"
    )
    print(job["message"])


if __name__ == "__main__":
    with recorded(__file__):
        main()
