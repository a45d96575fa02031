"""What the service can do right now, in words: the one place health, pages and buttons ask."""

from __future__ import annotations

import threading
import time
from typing import Any

from app.config import Settings
from app.storage import Storage
from weldpool_core.teacher.weights import weights_status


def _missing(what: str, statuses: list[Any]) -> str | None:
    """ "<what>: its weights are missing (settings) ..." with the fix, or None."""
    missing = [status for status in statuses if not status.available]
    if not missing:
        return None
    names = " and ".join(s.setting for s in missing)
    return (
        f"{what}: its weights are missing ({names}). Run `weldpool weights fetch` on a machine "
        f"with internet access, or point {names} at a local folder, then restart."
    )


def teacher_problem(settings: Settings) -> str | None:
    """Why the teacher cannot run here (missing weights), in one sentence; None when it can."""
    return _missing(
        "The teacher cannot run",
        [
            weights_status(settings.dino, "WELDPOOL_DINO"),
            weights_status(settings.sam2, "WELDPOOL_SAM2"),
        ],
    )


def sam2_problem(settings: Settings) -> str | None:
    """Why SAM2 alone cannot run (clicks, boxes, embeddings, propagation), or None when it can:
    those need no DINO."""
    return _missing(
        "Clicks, boxes and propagation need SAM2", [weights_status(settings.sam2, "WELDPOOL_SAM2")]
    )


STORE_CHECK_TTL_S = 5.0
"""How long /health reuses the store's last answer (a check may wait on a store that hangs)."""


class StoreCheck:
    """The store's part of /health: one bounded check at a time (``Storage.problem``), its
    answer kept ``ttl_s`` so /health stays fast; while one request checks, the others get the
    previous answer."""

    def __init__(self, storage: Storage, ttl_s: float = STORE_CHECK_TTL_S) -> None:
        self.storage, self.ttl_s = storage, ttl_s
        self.backend = storage.remote.split("://", 1)[0] if storage.remote else "local"
        self._lock = threading.Lock()
        self._answer: dict[str, Any] | None = None
        self._checked_at = 0.0

    def _fresh(self) -> dict[str, Any] | None:
        if self._answer is not None and time.monotonic() - self._checked_at < self.ttl_s:
            return self._answer
        return None

    def __call__(self) -> dict[str, Any]:
        """``{"status": "ok"|"error", "backend", "detail"?}``."""
        answer = self._fresh()
        if answer is not None:
            return answer
        if not self._lock.acquire(blocking=self._answer is None):
            return self._answer or {}  # another request is checking: the previous answer
        try:
            answer = self._fresh()
            if answer is None:
                problem = self.storage.problem()
                answer = {"status": "error" if problem else "ok", "backend": self.backend}
                if problem:
                    answer["detail"] = problem
                self._answer, self._checked_at = answer, time.monotonic()
            return answer
        finally:
            self._lock.release()
