"""A pass that a process runs in a daemon thread every few seconds (reaping lost jobs, sweeping
the file store): an error is logged and never ends the thread."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import structlog

log = structlog.get_logger(__name__)


class Periodic:
    """Runs ``run_once`` every ``interval_s`` seconds between ``start`` and ``stop`` (the first
    time after ``first_after_s``, default ``interval_s``)."""

    def __init__(
        self,
        name: str,
        interval_s: float,
        run_once: Callable[[], Any],
        first_after_s: float | None = None,
    ) -> None:
        self.name, self.interval_s, self.run_once = name, interval_s, run_once
        self.first_after_s = interval_s if first_after_s is None else first_after_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"weldpool-{name}", daemon=True)

    def _loop(self) -> None:
        wait = self.first_after_s
        while not self._stop.wait(wait):
            wait = self.interval_s
            try:
                self.run_once()
            except Exception:  # a database hiccup must not end the pass
                log.exception("periodic.failed", task=self.name)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
