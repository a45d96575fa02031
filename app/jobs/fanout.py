"""Fan-out: one job's work in chunks that every worker it reaches shares.

The worker that claims the job (its owner) plans it: its items (frame ids) in chunks, one
``job_chunks`` row each — the job's scope kept in its own table, so its parameters stay small.
It then invites others by putting the job's id on its lane again, once per other thread of the
live workers able to run it; a worker that receives the id of a running job of a kind
registered ``fanout=True`` joins as a helper. Owner and helpers take chunks one at a time: the
conditional update that names a free chunk takes it, so no chunk is worked twice, on SQLite and
PostgreSQL alike. The owner reports the job's progress (chunks done
over all), waits for its helpers' last chunks, takes over a chunk whose worker is gone, and
gathers every chunk's result: one run, one progress, one cancel. A helper stops when the job is
no longer running (cancelled, finished, or its owner lost it), giving back a chunk it had not
finished.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import sqlalchemy as sa
import structlog

from app.core.db import updated_one
from app.core.models import JobChunk
from app.jobs.registry import JobContext

log = structlog.get_logger(__name__)

WAIT_S = 0.25
"""How often the owner looks at its helpers' chunks while it has none to take."""


class Fanout:
    """The chunks of ``ctx``'s job, of ``chunk`` items each: planned once by the owner
    (``plan``), the plan kept in ``job_chunks`` (the job's scope in its own table, never a list
    in its parameters), and taken by a conditional update, one worker each."""

    def __init__(self, ctx: JobContext, chunk: int) -> None:
        self.ctx = ctx
        self.chunk = max(1, chunk)
        self._items: dict[int, list[int]] = {}

    @property
    def count(self) -> int:
        return len(self._load_items())

    @property
    def size(self) -> int:
        return sum(len(items) for items in self._load_items().values())

    def items(self, index: int) -> list[int]:
        """The items (frame ids) of chunk ``index``."""
        return self._load_items()[index]

    def plan(self, items: Callable[[], list[int]]) -> None:
        """Split ``items()`` into chunks and record them, unless the job has a plan already (a
        retried job goes on with its plan: done chunks stay done)."""
        ctx = self.ctx
        with ctx.session_factory() as session:
            planned = session.scalar(
                sa.select(sa.func.count())
                .select_from(JobChunk)
                .where(JobChunk.job_id == ctx.job_id)
            )
            if planned:
                return
            values = items()
            rows = [
                {"job_id": ctx.job_id, "chunk": i, "items": values[start : start + self.chunk]}
                for i, start in enumerate(range(0, len(values), self.chunk))
            ]
            for start in range(0, len(rows), 1000):
                session.execute(sa.insert(JobChunk), rows[start : start + 1000])
            session.commit()

    def _load_items(self) -> dict[int, list[int]]:
        if not self._items:
            with self.ctx.session_factory() as session:
                self._items = {
                    chunk: list(items or [])
                    for chunk, items in session.execute(
                        sa.select(JobChunk.chunk, JobChunk.items).where(
                            JobChunk.job_id == self.ctx.job_id
                        )
                    )
                }
        return self._items

    def invite(self) -> int:
        """Put the job's id on its lane again for the other live workers' threads that can
        run it (at most one per chunk beyond the first); returns how many were invited."""
        from app.jobs.runner import able_workers

        queue, ctx = self.ctx.queue, self.ctx
        if queue is None or self.count < 2:
            return 0
        threads = able_workers(
            ctx.session_factory, ctx.settings.job_stale_after_s, ctx.kind, threads=True
        )
        invited = min(self.count - 1, max(0, threads - 1))
        for _ in range(invited):
            queue.enqueue(ctx.job_id, ctx.kind, ctx.priority)
        return invited

    def _take(self, index: int, worker: str | None = None) -> bool:
        """Take chunk ``index`` if nobody has (or ``worker``, gone, still holds it)."""
        held = JobChunk.worker_id.is_(None) if worker is None else JobChunk.worker_id == worker
        with self.ctx.session_factory() as session:
            taken = updated_one(
                session,
                sa.update(JobChunk)
                .where(
                    JobChunk.job_id == self.ctx.job_id,
                    JobChunk.chunk == index,
                    JobChunk.done.is_(False),
                    held,
                )
                .values(worker_id=self.ctx.worker_id),
            )
            session.commit()
        return taken

    def _taken(self) -> dict[int, tuple[str | None, bool]]:
        with self.ctx.session_factory() as session:
            rows = session.execute(
                sa.select(JobChunk.chunk, JobChunk.worker_id, JobChunk.done).where(
                    JobChunk.job_id == self.ctx.job_id
                )
            ).all()
        return {chunk: (worker, done) for chunk, worker, done in rows}

    def _take_over(self, taken: dict[int, tuple[str | None, bool]]) -> int | None:
        """A chunk whose worker is gone (no live worker row), taken by a conditional update."""
        from app.jobs.runner import worker_rows

        ctx = self.ctx
        live = {w.id for w in worker_rows(ctx.session_factory, ctx.settings.job_stale_after_s)}
        live.add(ctx.worker_id)
        for index, (worker, done) in sorted(taken.items()):
            if done or worker is None or worker in live:
                continue
            if self._take(index, worker):
                log.warning("job.chunk_taken_over", job_id=ctx.job_id, chunk=index, worker=worker)
                return index
        return None

    def chunks(self) -> Iterator[int]:
        """The chunks this worker works, one at a time: free ones first; then, for the owner,
        chunks of workers that are gone, waiting (with progress) while helpers finish theirs.
        Yielded chunks are this worker's until ``working`` ends."""
        while True:
            taken = self._taken()
            free = next((i for i, (worker, _) in sorted(taken.items()) if worker is None), None)
            if free is not None:
                if self._take(free):
                    yield free
                continue
            if self.ctx.helper or all(done for _, done in taken.values()):
                return
            orphan = self._take_over(taken)
            if orphan is not None:
                yield orphan
                continue
            self.ctx.progress(self.progress(taken), self.message(taken))
            time.sleep(WAIT_S)

    @contextmanager
    def working(self, index: int) -> Iterator[dict[str, Any]]:
        """Work chunk ``index``: the dict yielded is its result, stored when the block ends;
        a block that raises gives the chunk back for another worker."""
        result: dict[str, Any] = {}
        try:
            yield result
        except BaseException:
            self._give_back(index)
            raise
        with self.ctx.session_factory() as session:
            session.execute(
                sa.update(JobChunk)
                .where(JobChunk.job_id == self.ctx.job_id, JobChunk.chunk == index)
                .values(done=True, result=result)
            )
            session.commit()

    def _give_back(self, index: int) -> None:
        with self.ctx.session_factory() as session:
            session.execute(
                sa.update(JobChunk)
                .where(
                    JobChunk.job_id == self.ctx.job_id,
                    JobChunk.chunk == index,
                    JobChunk.worker_id == self.ctx.worker_id,
                    JobChunk.done.is_(False),
                )
                .values(worker_id=None)
            )
            session.commit()

    def progress(self, taken: dict[int, tuple[str | None, bool]] | None = None) -> float:
        taken = self._taken() if taken is None else taken
        return sum(1 for _, done in taken.values() if done) / max(1, len(taken))

    def message(self, taken: dict[int, tuple[str | None, bool]] | None = None) -> str:
        """ "18 of 62 frames on 2 workers"."""
        taken = self._taken() if taken is None else taken
        done = sum(len(self.items(i)) for i, (_, finished) in taken.items() if finished)
        workers = len({worker for worker, _ in taken.values() if worker is not None})
        return f"{done} of {self.size} frames on {workers} worker{'s' if workers != 1 else ''}"

    def results(self) -> list[dict[str, Any]]:
        """Every chunk's result, in chunk order."""
        with self.ctx.session_factory() as session:
            return [
                dict(result or {})
                for result in session.scalars(
                    sa.select(JobChunk.result)
                    .where(JobChunk.job_id == self.ctx.job_id, JobChunk.done.is_(True))
                    .order_by(JobChunk.chunk)
                )
            ]

    def workers(self) -> list[str]:
        """The workers that worked its chunks."""
        return sorted({worker for worker, _ in self._taken().values() if worker is not None})
