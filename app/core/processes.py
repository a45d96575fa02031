"""The service's processes: numpy work that would hold the GIL against a request's or a job's
own thread (a large import's label contents, a CVAT export's masks) runs there instead. One
pool, started on first use (``spawn``: the worker has threads, so never ``fork``), one process
per core up to ``MAX_PROCESSES``, kept until the service stops (``stop_processes``)."""

from __future__ import annotations

import multiprocessing
import os
import threading
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from weldpool_core.annotations.content import start_process

MAX_PROCESSES = 8
"""Most processes (~150 MB each): not one per core on a big worker."""

_lock = threading.Lock()
_pool: ProcessPoolExecutor | None = None


def process_pool() -> ProcessPoolExecutor:
    """The processes, started now when they are not running."""
    global _pool
    with _lock:
        if _pool is None:
            _pool = ProcessPoolExecutor(
                max_workers=min(max(2, os.cpu_count() or 2), MAX_PROCESSES),
                mp_context=multiprocessing.get_context("spawn"),
                initializer=start_process,
            )
        return _pool


def started() -> bool:
    """Whether the processes are running."""
    return _pool is not None


def forget_broken() -> None:
    """A process was killed (the pool is broken): the next use starts afresh."""
    global _pool
    with _lock:
        _pool = None


def stop_processes() -> None:
    """End the processes, if started (the service stops: a graceful stop of ``serve`` leaves
    none behind); a later use starts them again."""
    global _pool
    with _lock:
        pool, _pool = _pool, None
    if pool is not None:
        pool.shutdown(wait=True, cancel_futures=True)


TASKS_AHEAD = 4
"""Tasks in the processes ahead of their consumer (it holds a few tasks' results at most)."""


def mapped_ahead(
    function: Callable[[list[Any]], list[Any]], items: list[Any], chunk: int, start_from: int
) -> Iterator[Any]:
    """``function`` over ``items``, ``chunk`` items a task, in the processes a few tasks ahead
    of the consumer; yields its results one by one, in order, so their numpy work never holds
    the consumer's GIL (a CVAT export's writer). A task the processes cannot take (not
    startable, one died) is computed here, and so are all of fewer than ``start_from`` items
    while the processes are not running (their start takes seconds)."""
    tasks = [items[at : at + chunk] for at in range(0, len(items), chunk)]
    if len(items) < start_from and not started():
        for task in tasks:
            yield from function(task)
        return
    pending: deque[Future[list[Any]] | None] = deque()
    try:
        for index, task in enumerate(tasks):
            for ahead in tasks[index + len(pending) : index + TASKS_AHEAD]:
                pending.append(_submitted(function, ahead))
            future = pending.popleft()
            try:
                results = future.result() if future is not None else function(task)
            except BrokenProcessPool:
                forget_broken()  # the next use starts them afresh
                results = function(task)
            yield from results
    finally:
        for future in pending:
            if future is not None:
                future.cancel()


def _submitted(function: Callable[[list[Any]], list[Any]], task: list[Any]) -> Future[Any] | None:
    try:
        return process_pool().submit(function, task)
    except (BrokenProcessPool, OSError, RuntimeError):  # cannot start, or shutting down
        return None
