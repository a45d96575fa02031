"""The service's processes: numpy work that would hold the GIL against a request's or a job's
own thread (a large import's label contents, a CVAT export's masks) runs there instead. One
pool, started on first use (``spawn``: the worker has threads, so never ``fork``), one process
per core up to ``MAX_PROCESSES``, kept until the service stops (``stop_processes``)."""

from __future__ import annotations

import multiprocessing
import os
import threading
from concurrent.futures import ProcessPoolExecutor

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
