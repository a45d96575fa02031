"""A busy lab for a minute: clients upload, list, label and delete at once; 0 × 5xx, 0 lost.

Eight clients (by default) upload runs of frames drawn from a shared pool of contents, list,
label and delete runs, and race: a run of new files is deleted while the same files are
uploaded to another run, the race in which a deletion used to remove files an upload had just
acknowledged. Every frame an upload acknowledged is read back at the end unless its run was
deleted after it; one that answers anything but its bytes is lost. Prints the requests per
kind, 5xx and lost frames.

    .venv/bin/python bench/load.py                          # SQLite, embedded worker
    .venv/bin/python bench/load.py --postgres --redis       # PostgreSQL + Redis (local ones)
"""

from __future__ import annotations

import argparse
import random
import threading
import time
import uuid
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import cv2
import httpx
import numpy as np
from common import local_server
from results import recorded

POSTGRES = "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
REDIS = "redis://127.0.0.1:6379/0"


def frame_png(seed: int) -> bytes:
    """A small distinct gray frame."""
    pixels = np.random.default_rng(seed).integers(0, 255, (120, 160), dtype=np.uint8)
    return bytes(cv2.imencode(".png", pixels)[1])


class Lab:
    """What the clients did and saw, shared between their threads."""

    def __init__(self, contents: list[bytes]) -> None:
        self.contents = contents
        self.lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.errors: list[str] = []
        self.acknowledged: dict[int, tuple[int, int]] = {}  # frame id: (run, content index)
        self.deleted_runs: set[int] = set()
        self.runs: list[int] = []

    def saw(self, kind: str, response: httpx.Response) -> None:
        with self.lock:
            self.counts[kind] += 1
            if response.status_code >= 500:
                self.errors.append(f"{kind} {response.status_code}: {response.text[:200]}")


def client_loop(url: str, token: str, lab: Lab, seconds: float, seed: int) -> None:
    rng = random.Random(seed)
    headers = {"Authorization": f"Bearer {token}"}
    deadline = time.monotonic() + seconds
    with httpx.Client(base_url=url, headers=headers, timeout=120) as http:
        while time.monotonic() < deadline:
            try:
                act(url, token, http, lab, rng, seed)
            except httpx.TransportError as exc:  # e.g. a kept-alive connection the server closed
                with lab.lock:
                    lab.counts[f"transport error ({type(exc).__name__})"] += 1


def act(url: str, token: str, http: httpx.Client, lab: Lab, rng: random.Random, seed: int) -> None:
    """One action of a client."""
    action = rng.choices(["upload", "list", "label", "delete", "race"], [5, 3, 2, 1, 1])[0]
    if action == "race":  # a run of its own files, deleted while they are sent again
        with lab.lock:
            fresh = list(range(len(lab.contents), len(lab.contents) + 6))
            lab.contents += [frame_png(seed * 10**6 + i) for i in fresh]
        if (run := upload(http, lab, fresh)) is None:
            return
        with lab.lock:
            lab.runs.remove(run)
            lab.deleted_runs.add(run)
        delete = threading.Thread(target=delete_run, args=(url, token, lab, run))
        delete.start()
        upload(http, lab, fresh)
        delete.join()
    elif action == "upload" or not lab.runs:
        upload(http, lab, rng.sample(range(len(lab.contents)), 6))
    elif action == "list":
        lab.saw("list", http.get("/api/v1/frames", params={"limit": 50}))
        lab.saw("list", http.get("/api/v1/sequences"))
    elif action == "label":
        with lab.lock:
            ids = list(lab.acknowledged)
        if ids:
            frame_id = rng.choice(ids)
            answer = http.put(
                f"/api/v1/frames/{frame_id}/label",
                json={"status": "rejected", "base_revision": 0},
            )
            lab.saw("label", answer)
    else:
        with lab.lock:
            run = lab.runs.pop(rng.randrange(len(lab.runs)))
            lab.deleted_runs.add(run)  # before the request: its frames may go any time
        delete_run(url, token, lab, run)


def upload(http: httpx.Client, lab: Lab, chosen: list[int]) -> int | None:
    """A new run with the frames ``chosen`` (indices into the contents); its id if stored."""
    created = http.post("/api/v1/sequences", json={"name": f"run {uuid.uuid4().hex[:8]}"})
    lab.saw("sequence", created)
    if created.status_code != 201:
        return None
    run = created.json()["id"]
    files = [("files", (f"{i}.png", lab.contents[i], "image/png")) for i in chosen]
    answer = http.post("/api/v1/frames", files=files, data={"sequence_id": str(run)})
    lab.saw("upload", answer)
    if answer.status_code == 201:
        with lab.lock:
            lab.runs.append(run)
            for frame in answer.json()["stored"]:
                index = int(frame["original_name"].removesuffix(".png"))
                lab.acknowledged[frame["id"]] = (run, index)
        return run
    return None


def delete_run(url: str, token: str, lab: Lab, run: int) -> None:
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}) as http:
        answer = http.delete(f"/api/v1/sequences/{run}", params={"force": "true"}, timeout=120)
    lab.saw("delete", answer)


def lost_frames(url: str, token: str, lab: Lab) -> tuple[int, int]:
    """(frames read back, frames lost) of the acknowledged ones whose run was kept."""
    headers = {"Authorization": f"Bearer {token}"}
    kept = {f: v for f, v in lab.acknowledged.items() if v[0] not in lab.deleted_runs}
    lost = 0
    for frame_id, (_, index) in kept.items():
        try:  # a connection per read: a server that fails mid-response resets it
            image = httpx.get(f"{url}/api/v1/frames/{frame_id}/image", headers=headers)
        except httpx.TransportError:
            lost += 1
            continue
        lost += image.status_code != 200 or image.content != lab.contents[index]
    return len(kept), lost


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--contents", type=int, default=120, help="distinct frames shared")
    parser.add_argument("--postgres", action="store_true", help=f"use {POSTGRES} (a schema)")
    parser.add_argument("--redis", action="store_true", help=f"use {REDIS}")
    args = parser.parse_args()
    env: dict[str, str] = {"WELDPOOL_RETRAIN_EVERY": "0"}
    schema = f"wp_load_{uuid.uuid4().hex[:8]}"
    if args.postgres:
        import sqlalchemy as sa

        with sa.create_engine(POSTGRES).begin() as connection:
            connection.execute(sa.text(f'CREATE SCHEMA "{schema}"'))
        env["WELDPOOL_DATABASE_URL"] = f"{POSTGRES}?options=-csearch_path%3D{schema}"
    if args.redis:
        env |= {"WELDPOOL_QUEUE_URL": REDIS, "WELDPOOL_QUEUE_NAME": schema}
    lab = Lab([frame_png(5000 + i) for i in range(args.contents)])
    try:
        with local_server(env) as (url, token):
            started = time.monotonic()
            with ThreadPoolExecutor(args.clients) as pool:
                for future in [
                    pool.submit(client_loop, url, token, lab, args.seconds, seed)
                    for seed in range(args.clients)
                ]:
                    future.result()
            took = time.monotonic() - started
            kept, lost = lost_frames(url, token, lab)
    finally:
        if args.postgres:
            with sa.create_engine(POSTGRES).begin() as connection:
                connection.execute(sa.text(f'DROP SCHEMA "{schema}" CASCADE'))
    backend = ("PostgreSQL" if args.postgres else "SQLite") + (" + Redis" if args.redis else "")
    print(f"| {backend}: {args.clients} clients × {took:.0f} s | requests |")
    print("|---|---:|")
    for kind, count in sorted(lab.counts.items()):
        print(f"| {kind} | {count} |")
    print(f"| 5xx | {len(lab.errors)} |")
    print(f"| frames acknowledged / read back from kept runs | {len(lab.acknowledged)} / {kept} |")
    print(f"| lost | {lost} |")
    for error in lab.errors[:5]:
        print("  ", error)


if __name__ == "__main__":
    with recorded(__file__):
        main()
