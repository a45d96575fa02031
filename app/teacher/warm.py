"""Embeddings made before the first click: the review page asks for its frame's, then for the
next frames' of its queue, when it opens (``POST /frames/{id}/embedding``).

One thread of the web process computes them through the one cache seam
(``teacher.cache.cached_embedding``), so the click that follows finds the embedding in this
process's memory, where clicks are answered; a click that comes meanwhile waits for the same
computation instead of starting another. The budget is bounded: at most ``MAX_PENDING``
embeddings wait or run at once (the rest are refused as ``busy``, and the page asks again
later), and the memory cache keeps the newest ``memory_items``.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Literal

from app.core import budgets
from app.core.config import Settings
from app.core.models import Frame
from app.storage import Storage
from app.storage.pixels import stored_rgb
from app.teacher import runtime

MAX_PENDING = 3
"""Embeddings waiting or computing at once: the frame open and the next two of its queue."""
State = Literal["ready", "computing", "busy", "cold"]
"""ready: in memory; computing: on its way; busy: not started, the budget is spent; cold:
neither (a look that does not start it)."""

_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="warm-embedding")
_lock = threading.Lock()
_pending: dict[str, tuple[Future[None], float]] = {}  # key → (computation, when it was asked)
_durations: deque[float] = deque(maxlen=20)  # ms of recent computations: the expected time


@dataclass(frozen=True)
class Warmth:
    state: State
    elapsed_ms: float | None = None
    expected_ms: float | None = None


def _expected() -> float | None:
    return statistics.median(_durations) if _durations else None


def _compute(
    storage: Storage, settings: Settings, sha256: str, path: str, size: tuple[int, int]
) -> None:
    from weldpool_core.teacher.cache import cached_embedding  # the ML stack: on first use

    start = time.perf_counter()
    predictor = runtime.sam2_predictor(settings)
    with budgets.interactive(settings):  # a reviewer waits for it: the click's budget
        _, tier = cached_embedding(
            predictor,
            runtime.embedding_cache(settings),
            sha256,
            lambda: stored_rgb(storage, path),
            size,
        )
    if tier == "computed":
        _durations.append((time.perf_counter() - start) * 1000)


def warmth(storage: Storage, settings: Settings, frame: Frame, *, start: bool) -> Warmth:
    """Where the frame's embedding stands; ``start`` begins computing it when it is neither in
    memory nor on its way (unless the budget is spent: ``busy``)."""
    from weldpool_core.teacher.cache import embedding_key

    predictor = runtime.sam2_predictor(settings)  # WeightsUnavailableError: 503, as a click
    key = embedding_key(frame.sha256, predictor.cache_identity)
    with _lock:
        for done in [k for k, (future, _) in _pending.items() if future.done()]:
            del _pending[done]
        # A computation still running is "computing" even once its embedding is in memory:
        # it has not recorded its duration yet, which "ready" reports as the expected time.
        if key in _pending:
            asked = _pending[key][1]
            return Warmth("computing", (time.monotonic() - asked) * 1000, _expected())
        if runtime.embedding_cache(settings).in_memory(key):
            return Warmth("ready", expected_ms=_expected())
        if not start:
            return Warmth("cold", expected_ms=_expected())
        if len(_pending) >= MAX_PENDING:
            return Warmth("busy", expected_ms=_expected())
        future = _pool.submit(
            _compute, storage, settings, frame.sha256, frame.path, (frame.height, frame.width)
        )
        _pending[key] = (future, time.monotonic())
    return Warmth("computing", 0.0, _expected())
