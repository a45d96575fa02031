"""Thread and priority budgets: a click's threads, a job's priority and its yielding."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch
from fastapi.testclient import TestClient

from app.core import budgets
from app.core.config import Settings
from app.core.models import Role
from tests.helpers import auth, make_settings, wait_for_job


def _in_thread(work: Callable[[], Any]) -> Any:
    """``work`` in a new thread (torch threads and nice are per thread); its result."""
    out: dict[str, Any] = {}

    def run() -> None:
        try:
            out["value"] = work()
        except BaseException as exc:  # re-raised in the test's thread
            out["error"] = exc

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    if "error" in out:
        raise out["error"]
    return out["value"]


@pytest.fixture
def four_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    """torch's own count is 4 here, so that every budget has its own number."""
    monkeypatch.setattr(budgets, "default_threads", lambda: 4)


def _settings(tmp_path: Path, **overrides: Any) -> Settings:
    settings = make_settings(tmp_path / "home", **overrides)
    settings.ensure_home()
    return settings


def _age(path: Path, seconds: float) -> None:
    old = time.time() - seconds
    os.utime(path, (old, old))


def _click_threads(settings: Settings) -> int:
    """A click's torch threads (in a pool-like thread, whose own count comes back after)."""

    def click() -> int:
        torch.set_num_threads(3)
        with budgets.interactive(settings):
            inside = torch.get_num_threads()
        assert torch.get_num_threads() == 3
        return inside

    return int(_in_thread(click))


def test_a_click_uses_every_core_when_quiet_and_its_budget_beside_a_job(
    tmp_path: Path, four_cores: None
) -> None:
    settings = _settings(tmp_path)
    before = torch.get_num_threads()
    assert _click_threads(settings) == 4  # no job on this machine
    assert torch.get_num_threads() == before  # another thread's count is its own
    _in_thread(lambda: budgets.start_batch(settings))  # a job reports progress
    assert budgets.job_running(settings)
    assert _click_threads(settings) == 2  # half the cores
    assert _click_threads(_settings(tmp_path / "other", interactive_threads=3)) == 4  # quiet
    assert _click_threads(_settings(tmp_path, interactive_threads=3)) == 3  # beside the job
    _age(settings.home / budgets.BATCH_FILE, budgets.BATCH_FRESH_S + 1)
    assert not budgets.job_running(settings)
    assert _click_threads(settings) == 4


def test_a_job_runs_niced_with_its_threads_and_yields_while_a_reviewer_clicks(
    tmp_path: Path, four_cores: None
) -> None:
    settings = _settings(tmp_path, batch_nice=7, reviewer_active_s=20)
    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    job_started = threading.Event()
    step = threading.Event()
    seen: list[tuple[int, int]] = []

    def job() -> None:
        budgets.start_batch(settings)
        seen.append((os.getpriority(os.PRIO_PROCESS, threading.get_native_id()), 0))
        seen.append((torch.get_num_threads(), 1))
        job_started.set()
        for _ in range(2):
            step.wait(10)
            step.clear()
            budgets.batch_checkpoint(settings, force=True)
            seen.append((torch.get_num_threads(), 2))

    thread = threading.Thread(target=job)
    thread.start()
    assert job_started.wait(10)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base  # not this one
    with budgets.interactive(settings):  # a reviewer clicks
        pass
    assert budgets.reviewer_active(settings)
    step.set()
    time.sleep(0.2)
    _age(settings.home / budgets.ACTIVE_FILE, 21)  # the reviewer left 21 s ago
    step.set()
    thread.join(10)
    assert seen == [(min(19, base + 7), 0), (4, 1), (2, 2), (4, 2)]


def test_jobs_of_the_embedded_worker_run_on_the_batch_budget(
    monkeypatch: pytest.MonkeyPatch, client: TestClient, make_user: Any, settings: Settings
) -> None:
    """Every job starts niced, and reports each progress to the batch budget."""
    calls: list[tuple[int, int]] = []
    checkpoint = budgets.batch_checkpoint

    def recording(settings: Settings, *, force: bool = False) -> None:
        tid = threading.get_native_id()
        calls.append((tid, os.getpriority(os.PRIO_PROCESS, tid)))
        checkpoint(settings, force=force)

    monkeypatch.setattr(budgets, "batch_checkpoint", recording)
    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    _, token = make_user("lead", Role.admin)
    started = client.post("/api/v1/jobs/diagnostic", json={"seconds": 0.6}, headers=auth(token))
    assert started.status_code == 202, started.text
    job = started.json()["job_id"]
    assert wait_for_job(client, job, token)["status"] == "succeeded"
    assert len(calls) >= 2  # the start, then each progress report
    assert {nice for _, nice in calls} == {min(19, base + settings.batch_nice)}
    assert threading.get_native_id() not in {tid for tid, _ in calls}


def test_a_shared_pool_s_threads_do_not_take_a_job_s_priority(tmp_path: Path) -> None:
    """Threads inherit the nice of the thread that starts them: a pool shared by uploads and
    jobs has all its threads started where it is made, so a job's submit starts none."""
    settings = _settings(tmp_path, batch_nice=5)
    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    pool = budgets.shared_pool(3, "test-shared")

    def from_a_job() -> set[int]:
        budgets.start_batch(settings)
        barrier = threading.Barrier(3)

        def nice() -> int:
            barrier.wait(5)  # three tasks at once: each on its own thread
            return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

        return {future.result() for future in [pool.submit(nice) for _ in range(3)]}

    assert _in_thread(from_a_job) == {base}
    pool.shutdown()
