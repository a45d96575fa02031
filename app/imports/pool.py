"""Where a batch's label contents are computed (rasterise, encode, Algorithm 1): in processes,
one per core, for a large import, else in the ingest threads; waited for with the import's
check (a cancel, a deactivated user) asked every ``CHECK_S``, so it lands during a label's work,
not only between batches."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from app.core.processes import forget_broken, process_pool
from app.frames.ingest import INGEST_POOL
from weldpool_core.annotations import ImportedLabel
from weldpool_core.annotations.content import (
    LabelContent,
    label_content,
    many_contents,
    shipped,
)

BATCH = 64  # a batch has 8 tasks: as many as the service's processes at most
PROCESS_CHUNK = 8
"""Labels per task sent to a process (fewer round trips)."""
CHECK_S = 0.5
"""How often an import asks whether to go on while its labels are computed."""
Check = Callable[[], None]
Job = tuple[ImportedLabel, tuple[int, int], bool]


def waited(futures: list[Future[Any]], check: Check | None) -> None:
    """Wait for ``futures``, calling ``check`` every ``CHECK_S`` until they are done; when it
    raises, the futures not started yet are cancelled (a started label finishes unread)."""
    pending = set(futures)
    try:
        while pending:
            _, pending = wait(pending, timeout=CHECK_S)
            if pending and check is not None:
                check()
    except BaseException:
        for future in futures:
            future.cancel()
        raise


class Contents:
    """The contents of a batch's labels being computed: in the processes (``shipped`` labels,
    a few per task) or in the ingest threads; a broken process pool falls back to threads."""

    def __init__(self, jobs: list[Job], processes: bool):
        self.jobs = jobs
        self.futures: list[Future[list[LabelContent]]] = []
        self.threads: list[Future[LabelContent]] = []
        if processes and jobs:
            try:
                pool = process_pool()  # the service's (app.core.processes)
                self.futures = [
                    pool.submit(
                        many_contents,
                        [(shipped(i), size, w) for i, size, w in jobs[at : at + PROCESS_CHUNK]],
                    )
                    for at in range(0, len(jobs), PROCESS_CHUNK)
                ]
            except (BrokenProcessPool, OSError, RuntimeError):
                self.futures = []
        if not self.futures:
            self.threads = [INGEST_POOL.submit(label_content, *job) for job in jobs]

    def results(self, check: Check | None = None) -> list[LabelContent]:
        try:
            if self.futures:
                waited(self.futures, check)
                return [c for f in self.futures for c in f.result()]
        except BrokenProcessPool:  # a process was killed: start afresh next time
            forget_broken()
            self.threads = [INGEST_POOL.submit(label_content, *job) for job in self.jobs]
        waited(self.threads, check)
        return [f.result() for f in self.threads]


def computed(jobs: list[Job], check: Check | None = None) -> list[LabelContent]:
    """The contents of ``jobs`` computed now, in the ingest threads."""
    futures = [INGEST_POOL.submit(label_content, *job) for job in jobs]
    waited(futures, check)
    return [f.result() for f in futures]
