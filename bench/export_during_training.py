"""An export asked while the default student trains, on the defaults (the embedded worker, one
model thread): the quick lane's export against the same export in a quiet instance (goal: it
ends before the training does, within max(30 s, 10× its quiet time)).

`weldpool demo` fills a throw-away home (SQLite, the SQLite queue) with labelled frames; then
`weldpool serve` with its embedded worker: a quiet COCO export timed from the request to its
end (median of runs), a training started with the defaults, and, once it runs, the same export
timed again while the training goes on (then the training is cancelled). Prints the table and
records it (``docs/benchmarks/export_during_training.json``).

    PYTHONPATH=. .venv/bin/python bench/export_during_training.py [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import httpx
from common import local_server
from results import Table, record


def _wait(url: str, headers: dict[str, str], job: int, until: tuple[str, ...]) -> dict:
    while True:
        state = httpx.get(f"{url}/api/v1/jobs/{job}", headers=headers, timeout=30).json()
        if state["status"] in until:
            return state
        time.sleep(0.1)


def _export(url: str, headers: dict[str, str]) -> float:
    start = time.perf_counter()
    job = httpx.post(
        f"{url}/api/v1/exports", json={"format": "coco"}, headers=headers, timeout=30
    ).json()["job_id"]
    state = _wait(url, headers, job, ("succeeded", "failed", "cancelled"))
    if state["status"] != "succeeded":
        raise SystemExit(f"the export ended {state['status']}: {state['error']}")
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    with local_server(setup=[("demo",)]) as (url, token):
        headers = {"Authorization": f"Bearer {token}"}
        quiet = [_export(url, headers) for _ in range(args.runs)]
        train = httpx.post(f"{url}/api/v1/student/train", json={}, headers=headers, timeout=30)
        training = train.json()["job_id"]
        _wait(url, headers, training, ("running", "succeeded", "failed"))
        busy, still_training = [], []
        for _ in range(args.runs):
            busy.append(_export(url, headers))
            state = httpx.get(f"{url}/api/v1/jobs/{training}", headers=headers, timeout=30).json()
            still_training.append(state["status"] == "running")
        httpx.post(f"{url}/api/v1/jobs/{training}/cancel", headers=headers, timeout=30)
    quiet_s, busy_s = statistics.median(quiet), statistics.median(busy)
    goal = max(30.0, 10 * quiet_s)
    table = Table(
        "a COCO export of the demo's labels, quiet and while the default student trains "
        "(the embedded worker, one model thread)",
        ["export", "median s", "runs s", "ratio to quiet", "goal s", "training still running"],
        [
            ["quiet", f"{quiet_s:.2f}", " ".join(f"{t:.2f}" for t in quiet), "1.00×", "", ""],
            [
                "during training",
                f"{busy_s:.2f}",
                " ".join(f"{t:.2f}" for t in busy),
                f"{busy_s / quiet_s:.2f}×",
                f"≤ {goal:.0f}",
                f"{sum(still_training)} of {len(still_training)}",
            ],
        ],
        align=["left", "right", "right", "right", "right", "left"],
    )
    print(table.markdown())
    record(
        "bench/export_during_training.py",
        [table],
        f"PYTHONPATH=. .venv/bin/python bench/export_during_training.py --runs {args.runs}",
    )


if __name__ == "__main__":
    main()
