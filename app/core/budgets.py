"""Thread and priority budgets: a reviewer's click is never queued behind a job for the CPU.

On one machine the web process answers clicks while the worker (embedded, or a ``weldpool
worker`` beside it) runs teacher jobs, embeddings in bulk, training, propagation and exports.
Each side gets its own budget from the settings:

- **interactive** (a click, a box, an embedding a reviewer waits for): every core while no job
  runs on this machine, ``interactive_threads`` while one does (under contention a second
  thread buys a click nothing), at the process's own priority. It also marks a reviewer as
  active, for this process and for workers sharing the home folder (a file's time).
- **batch** (every job): the job's thread runs ``batch_nice`` lower (Linux nice is per thread,
  and the OpenMP threads torch starts from it inherit it), with ``batch_threads`` torch threads;
  while a reviewer is active it may run with the cores a click leaves (``reviewer_active_s``),
  checked at each progress report (after every training batch, every teacher frame). A job
  marks itself running the same way (a file's time), which is how a click knows.

torch's thread count is per calling thread (OpenMP's ``nthreads`` ICV, MKL's local count), so
the two budgets hold side by side in one process; a click's count is put back when it is done,
as threads started later copy the last count set. A job applies its count only once torch is
loaded (a job without models never loads it); a click loads it, as its model needs it anyway.
Budgets are advice: nothing here raises into a job or a request. Threads inherit the priority
of the thread that starts them, so the thread pools that requests and jobs share are started
from the process's own priority (``shared_pool``), never from a job's.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import structlog

from app.core.config import Settings

ACTIVE_FILE = "reviewer-active"
"""In the home folder: its modification time is the last interactive request on this machine."""
BATCH_FILE = "job-running"
"""In the home folder: its modification time is the last progress of a job on this machine."""
TOUCH_EVERY_S = 1.0  # a file's time is refreshed at most this often
LOOK_EVERY_S = 0.5  # a job reads the reviewer's at most this often
BATCH_FRESH_S = 5.0  # a job that reported this recently is running (reports come every batch)

log = structlog.get_logger(__name__)
_local = threading.local()
_touched: dict[Path, float] = {}


@functools.cache
def default_threads() -> int:
    """torch's thread count before any budget set one: the machine's physical cores, or
    ``OMP_NUM_THREADS`` when the user set it (torch must be loaded)."""
    return max(1, int(sys.modules["torch"].get_num_threads()))


def interactive_threads(settings: Settings, *, job_running: bool = True) -> int:
    """A click's threads: every core on a quiet machine, fewer beside a running job."""
    full = settings.batch_threads or default_threads()
    if not job_running:
        return full
    return settings.interactive_threads or max(1, full // 2)


def batch_threads(settings: Settings, *, reviewer_active: bool = False) -> int:
    """A job's threads: all of them, or those a click leaves while a reviewer is active."""
    full = settings.batch_threads or default_threads()
    if reviewer_active:
        return max(1, full - interactive_threads(settings))
    return full


def _loaded_torch() -> Any:
    """torch if its import has finished (another thread may be importing it), else None."""
    torch = sys.modules.get("torch")
    if torch is None or getattr(getattr(torch, "__spec__", None), "_initializing", False):
        return None
    return torch


def _set_torch_threads(count: Callable[[], int]) -> None:
    torch = _loaded_torch()
    if torch is not None:
        torch.set_num_threads(count())


def _touch(path: Path) -> None:
    now = time.monotonic()
    if now - _touched.get(path, 0.0) < TOUCH_EVERY_S:
        return
    _touched[path] = now
    with contextlib.suppress(OSError):  # a read-only or missing home: advice, never an error
        path.touch()


def _within(path: Path, seconds: float) -> bool:
    if seconds <= 0:
        return False
    try:
        return time.time() - path.stat().st_mtime < seconds
    except OSError:
        return False


def mark_reviewer_active(settings: Settings) -> None:
    """A reviewer just asked for interactive work (recorded only where jobs look at it)."""
    if settings.reviewer_active_s > 0:
        _touch(settings.marker(ACTIVE_FILE))


def reviewer_active(settings: Settings) -> bool:
    """Whether a reviewer on this machine made an interactive request recently."""
    return _within(settings.marker(ACTIVE_FILE), settings.reviewer_active_s)


def job_running(settings: Settings) -> bool:
    """Whether a job on this machine (sharing the home folder) reported progress just now."""
    return _within(settings.marker(BATCH_FILE), BATCH_FRESH_S)


@contextmanager
def interactive(settings: Settings) -> Iterator[None]:
    """Run a reviewer's request on the interactive budget (this thread's torch threads, put
    back afterwards)."""
    mark_reviewer_active(settings)
    import torch  # the request runs a model: torch is needed now anyway

    before = torch.get_num_threads()
    torch.set_num_threads(interactive_threads(settings, job_running=job_running(settings)))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def lower_priority(nice: int) -> None:
    """This thread (only) ``nice`` lower than the process; never raised back (that would need
    privileges). Linux only: elsewhere a thread's priority is the process's."""
    if nice <= 0 or getattr(_local, "nice", 0) >= nice or not sys.platform.startswith("linux"):
        return
    try:
        tid = threading.get_native_id()
        base = os.getpriority(os.PRIO_PROCESS, os.getpid())
        os.setpriority(os.PRIO_PROCESS, tid, min(19, base + nice))
        _local.nice = nice
    except (OSError, AttributeError):  # not permitted here: the thread keeps its priority
        pass


def start_batch(settings: Settings) -> None:
    """A job starts in this thread: lower its priority, give it the batch budget."""
    try:
        lower_priority(settings.batch_nice)
    except Exception:  # advice, never a failed job
        log.warning("budgets.start_failed", exc_info=True)
    batch_checkpoint(settings, force=True)


def batch_checkpoint(settings: Settings, *, force: bool = False) -> None:
    """Between two chunks of a job: fewer threads while a reviewer is active, all again after."""
    try:
        _touch(settings.marker(BATCH_FILE))
        now = time.monotonic()
        if not force and now - getattr(_local, "looked", 0.0) < LOOK_EVERY_S:
            return
        _local.looked = now
        active = reviewer_active(settings)
        _set_torch_threads(lambda: batch_threads(settings, reviewer_active=active))
    except Exception:  # advice, never a failed job
        log.warning("budgets.checkpoint_failed", exc_info=True)


def shared_pool(workers: int, prefix: str) -> ThreadPoolExecutor:
    """A thread pool that requests and jobs share, its threads all started now, from this
    thread: a thread takes the priority of the thread that starts it, and a pool whose threads
    a niced job started would serve later uploads at the job's priority."""
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=prefix)
    started = threading.Barrier(workers + 1)
    for _ in range(workers):  # each waits until all are running: every submit starts a thread
        pool.submit(started.wait, 10)
    with contextlib.suppress(threading.BrokenBarrierError):
        started.wait(10)
    return pool
