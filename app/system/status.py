"""What the service can do right now, in words: the one place health, pages and buttons ask."""

from __future__ import annotations

import threading
import time
from typing import Any

from app.core.config import Settings
from app.storage import Storage, open_storage
from weldpool_core.teacher.weights import weights_status


def _missing(what: str, statuses: list[Any], admin: bool) -> str | None:
    """ "<what>: its weights are missing (settings) ..." with the fix, or None. Only an admin
    can install weights: anyone else is told to ask one."""
    missing = [status for status in statuses if not status.available]
    if not missing:
        return None
    names = " and ".join(s.setting for s in missing)
    if not admin:
        return (
            f"{what}: its weights are missing ({names}). Ask an admin to install them "
            '(Help, "Weights").'
        )
    return (
        f"{what}: its weights are missing ({names}). Run `weldpool weights fetch` on a machine "
        f"with internet access, or point {names} at a local folder, then restart."
    )


def teacher_problem(settings: Settings, *, admin: bool = True) -> str | None:
    """Why the teacher cannot run here (missing weights), in one sentence; None when it can.
    ``admin``: the fix is the commands; otherwise, to ask an admin."""
    return _missing(
        "The teacher cannot run",
        [
            weights_status(settings.dino, "WELDPOOL_DINO"),
            weights_status(settings.sam2, "WELDPOOL_SAM2"),
        ],
        admin,
    )


def sam2_problem(settings: Settings, *, admin: bool = True) -> str | None:
    """Why SAM2 alone cannot run (clicks, boxes, embeddings, propagation), or None when it can:
    those need no DINO."""
    return _missing(
        "Clicks, boxes and propagation need SAM2",
        [weights_status(settings.sam2, "WELDPOOL_SAM2")],
        admin,
    )


STORE_SAMPLE = 3
"""How many of the newest frames a worker looks for in its store at start."""


def foreign_store(settings: Settings, session_factory: Any) -> str | None:
    """Why a worker with these settings does not share the web process's file store, in one
    sentence, or None: its store holds none of the newest frames the database names (a worker
    on another machine without WELDPOOL_STORAGE_URL, or with another bucket, would fail every
    frame). No frames yet, or a store that does not answer, tells nothing: None."""
    import sqlalchemy as sa

    from app.core.models import Frame

    with session_factory() as session:
        paths = list(
            session.scalars(sa.select(Frame.path).order_by(Frame.id.desc()).limit(STORE_SAMPLE))
        )
    if not paths:
        return None
    storage = open_storage(settings, for_requests=True)
    try:
        if any(storage.holds(path) for path in paths):
            return None
    except Exception:  # an outage is not a foreign store: its jobs pause and retry
        return None
    where = "its object store" if storage.remote else "this machine's WELDPOOL_HOME"
    return (
        f"This worker's file store ({where}) holds none of the newest frames the database "
        "names; give it the web process's WELDPOOL_STORAGE_URL."
    )


def unable_kinds(
    settings: Settings, kinds: list[tuple[str, str]], session_factory: Any = None
) -> dict[str, str]:
    """The job kinds a worker with these settings cannot run, each with why in one sentence:
    every kind when its file store is not the web process's (``foreign_store``, checked when
    ``session_factory`` is given: a worker of its own), model-lane kinds without a usable
    device, the teacher without its weights, SAM2's kinds (embeddings, propagation) without
    SAM2's. ``kinds`` is every (kind, lane) it would serve."""
    from weldpool_core.device import resolve_device
    from weldpool_core.errors import InvalidInputError

    if session_factory is not None and (problem := foreign_store(settings, session_factory)):
        return {kind: problem for kind, _ in kinds}
    unable: dict[str, str] = {}
    try:
        if settings.device.strip().lower() != "auto":  # auto is always usable: no torch import
            resolve_device(settings.device)
    except InvalidInputError as exc:
        unable |= {kind: exc.message for kind, lane in kinds if lane == "model"}
    needs = {"teacher": teacher_problem(settings)}
    sam2 = sam2_problem(settings)
    needs |= {"embed": sam2, "propagate": sam2}
    for kind, problem in needs.items():
        if problem and kind not in unable and any(kind == k for k, _ in kinds):
            unable[kind] = problem
    return unable


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
