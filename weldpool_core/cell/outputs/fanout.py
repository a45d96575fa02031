"""The stream's outputs together (``Outputs``): each record to every output, one that fails
told once in the log while the others go on, and a watchdog that tells each output when frames
stop and when they resume."""

from __future__ import annotations

import threading
import time
from typing import Any

from weldpool_core.cell.outputs.base import CellInfo, Output, OutputStatus, Reporter, log


class Outputs:
    """The stream's outputs together: ``send`` to each, and a watchdog that tells each of them
    once when no frame has come for ``info.stale_ms`` (``output.stale``; armed by the first frame)
    and once when frames resume (``output.resumed``, before the next ``send``)."""

    def __init__(self, outputs: list[Output], info: CellInfo) -> None:
        self.outputs = outputs
        self.info = info
        self.reporter = Reporter("outputs")
        self._last: float | None = None  # armed by the first frame, not by the opening
        self._stale = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None
        if any(hasattr(output, "stale") for output in outputs):
            self._watchdog = threading.Thread(target=self._watch, name="outputs-watch", daemon=True)
            self._watchdog.start()

    def send(self, record: dict[str, Any]) -> None:
        """Hand the record to every output; one that fails is told once in the log and the
        others still get the frame (inference goes on)."""
        with self._lock:
            self._last = time.perf_counter()
            resumed, self._stale = self._stale, False
        for output in self.outputs:
            try:
                if resumed and hasattr(output, "resumed"):
                    output.resumed()
                output.send(record)
            except Exception as exc:
                self.reporter.problem(output.kind, f"{output.kind} failed ({exc}); it skips frames")

    def _watch(self) -> None:
        period = self.info.stale_ms / 4000.0
        while not self._stop.wait(period):
            with self._lock:
                if self._last is None or self._stale:
                    continue
                quiet_ms = 1000.0 * (time.perf_counter() - self._last)
                if quiet_ms < self.info.stale_ms:
                    continue
                self._stale = True
            for output in self.outputs:
                if hasattr(output, "stale"):
                    output.stale(quiet_ms)

    def statuses(self) -> list[OutputStatus]:
        return [output.status() for output in self.outputs]

    def close(self) -> None:
        self._stop.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=2)
        for output in self.outputs:
            try:
                output.close()
            except Exception:  # closing one must not leave the others open
                log.exception("%s: closing failed", output.kind)
