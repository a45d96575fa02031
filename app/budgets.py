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
the two budgets hold side by side in one process. Nothing here imports torch: a thread count is
applied only where torch is already loaded, as it is for any model work.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from app.config import Settings

ACTIVE_FILE = "reviewer-active"
"""In the home folder: its modification time is the last interactive request on this machine."""
BATCH_FILE = "job-running"
"""In the home folder: its modification time is the last progress of a job on this machine."""
TOUCH_EVERY_S = 1.0  # a file's time is refreshed at most this often
LOOK_EVERY_S = 0.5  # a job reads the reviewer's at most this often
BATCH_FRESH_S = 5.0  # a job that reported this recently is running (reports come every batch)

_local = threading.local()
_touched: dict[Path, float] = {}


_default: list[int] = []  # torch's own thread count in this process, read once


def default_threads() -> int:
    """torch's thread count before any budget set one: the machine's physical cores, or
    ``OMP_NUM_THREADS`` when the user set it (torch must be loaded)."""
    if not _default:
        _default.append(max(1, int(sys.modules["torch"].get_num_threads())))
    return _default[0]


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


def _set_torch_threads(count: Callable[[], int]) -> None:
    torch = sys.modules.get("torch")
    if torch is None:  # no model work in this thread yet; set once it has some
        return
    threads = count()
    if getattr(_local, "threads", None) != threads:
        torch.set_num_threads(threads)
        _local.threads = threads


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
    """A reviewer just asked for interactive work."""
    _touch(settings.home / ACTIVE_FILE)


def reviewer_active(settings: Settings) -> bool:
    """Whether a reviewer on this machine made an interactive request recently."""
    return _within(settings.home / ACTIVE_FILE, settings.reviewer_active_s)


def job_running(settings: Settings) -> bool:
    """Whether a job on this machine (sharing the home folder) reported progress just now."""
    return _within(settings.home / BATCH_FILE, BATCH_FRESH_S)


@contextmanager
def interactive(settings: Settings) -> Iterator[None]:
    """Run a reviewer's request on the interactive budget (this thread's torch threads)."""
    mark_reviewer_active(settings)
    import torch  # the request runs a model: torch is needed now anyway

    del torch
    running = job_running(settings)
    _set_torch_threads(lambda: interactive_threads(settings, job_running=running))
    yield


def _lower_priority(nice: int) -> None:
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
    _lower_priority(settings.batch_nice)
    _local.looked = 0.0
    batch_checkpoint(settings, force=True)


def batch_checkpoint(settings: Settings, *, force: bool = False) -> None:
    """Between two chunks of a job: fewer threads while a reviewer is active, all again after."""
    _touch(settings.home / BATCH_FILE)
    now = time.monotonic()
    if not force and now - getattr(_local, "looked", 0.0) < LOOK_EVERY_S:
        return
    _local.looked = now
    active = reviewer_active(settings)
    _set_torch_threads(lambda: batch_threads(settings, reviewer_active=active))


def current_threads() -> int | None:
    """The torch threads this thread was last given (None: none yet), for tests and logs."""
    return getattr(_local, "threads", None)
