"""Benchmark the process map over many weld runs with stored signatures.

Run: ``PYTHONPATH=. .venv/bin/python bench/process_map.py [--runs 1000]``

It fills N runs with process parameters along Rosenthal's law and a stored, fresh signature each
(no frames: a map never reads them while signatures are fresh), then times
``GET /api/v1/process-map`` in process (the whole request path, authentication included), the
server's part without HTTP (the map and its fit) and the floor (the bare SQL of the rows the map
reads). Median of 15 runs, milliseconds. The goal: under 100 ms for 1,000 runs.
"""

from __future__ import annotations

import argparse
import random
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from fastapi.testclient import TestClient
from results import recorded

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role, RunSignature, Sequence, User
from app.core.schema import migrate
from app.core.security import hash_password, issue_token
from app.main import create_app
from app.process.service import process_map
from app.storage import open_storage


def _fill(factory: Any, runs: int) -> str:
    rng = random.Random(7)
    with factory() as session:
        user = User(username="bench", password_hash=hash_password("x" * 12), role=Role.reviewer)
        session.add(user)
        session.flush()
        _, token = issue_token(session, user)
        for i in range(runs):
            volts, amps, speed = rng.uniform(18, 28), rng.uniform(120, 260), rng.uniform(25, 60)
            width = 0.3 * (volts * amps / (speed / 6)) ** 0.5 * rng.gauss(1, 0.03)
            values = {"voltage_v": volts, "current_a": amps, "robot_speed_cm_min": speed}
            run = Sequence(name=f"run {i}", wire_feed_m_min=8.0, mm_per_px=0.05, **values)
            session.add(run)
            session.flush()
            session.add(RunSignature(
                sequence_id=run.id, stale=False, policy_source="teacher", unit="mm", frames=300,
                measured=300, width=width, width_q1=width * 0.95, width_q3=width * 1.05,
                length=1.8 * width, length_q1=1.7 * width, length_q3=1.9 * width,
                area=1.4 * width**2, area_q1=1.3 * width**2, area_q3=1.5 * width**2,
                width_cv=rng.uniform(0.02, 0.12), oscillation_hz=rng.uniform(0.5, 7),
                oscillation_strength=rng.random(), unstable_frames=0, detail={},
            ))  # fmt: skip
        session.commit()
    return token


def _median_ms(call: Any, repeat: int = 15) -> float:
    call()  # warm
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        times.append(1000 * (time.perf_counter() - start))
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=1000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as home:
        settings = Settings(home=Path(home))
        engine = create_db_engine(settings.resolved_database_url)
        migrate(engine)
        factory = create_session_factory(engine)
        token = _fill(factory, args.runs)
        storage = open_storage(settings)
        params = {"x": "heat_input_j_mm", "y": "width_mm", "color": "width_cv"}
        with TestClient(create_app(settings)) as client:
            headers = {"Authorization": f"Bearer {token}"}
            answer = client.get("/api/v1/process-map", params=params, headers=headers)
            assert answer.status_code == 200 and len(answer.json()["points"]) == args.runs
            http = _median_ms(
                lambda: client.get("/api/v1/process-map", params=params, headers=headers)
            )

        def server() -> None:
            with factory() as session:
                process_map(session, storage, "heat_input_j_mm", "width_mm", "width_cv")

        def floor() -> None:
            with factory() as session:
                session.execute(sa.select(Sequence.id, RunSignature.width).join(RunSignature)).all()

        rows = [
            ["GET /api/v1/process-map (in process)", f"{http:.1f}"],
            ["the map and its fit, no HTTP", f"{_median_ms(server):.1f}"],
            ["floor: the bare SQL of the rows", f"{_median_ms(floor):.1f}"],
        ]
        print(f"\n### Process map of {args.runs} runs, SQLite (median of 15, ms)\n")
        print("| measured | ms |\n|---|---:|")
        for row in rows:
            print(f"| {row[0]} | {row[1]} |")
        print(f"\nfit b = {answer.json()['fit']['b']:.3f} (the law the runs were made with: 0.5)")
        engine.dispose()


if __name__ == "__main__":
    with recorded(__file__):
        main()
