"""Live views: the promoted (or a chosen) student on a camera, URL or video, inside the web process.

An engineer at the cell starts one from the models page; it runs ``weldpool_core.cell.stream`` on a
thread of this process (the ML stack is imported then, not before) and keeps what the page needs:
the newest frame with the mask outline and keypoints drawn (JPEG, at most ``OVERLAY_FPS`` a second,
so drawing never slows the student), the last ``KEEP_RECORDS`` records for the scrolling curves,
and fps and latency over the last ``STATS_WINDOW`` frames. At most ``MAX_RUNNING`` run at once;
a file plays at its own frame rate (as a camera would), and ends at its last frame. Views are
kept in memory only: a restart of the server ends them.
"""

from __future__ import annotations

import collections
import datetime as dt
import itertools
import threading
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog

from app.core.db import utcnow
from app.core.errors import ConflictError, InvalidInputError, NotFoundError, WeldpoolError

if TYPE_CHECKING:
    import cv2
    import numpy as np
else:
    from weldpool_core.lazy import cv2, np

log = structlog.get_logger(__name__)

MAX_RUNNING = 2
KEEP_ENDED = 20
"""Ended views kept for their page (the oldest beyond this are forgotten)."""
KEEP_RECORDS = 900
STATS_WINDOW = 120
OVERLAY_FPS = 12.0
OVERLAY_WIDTH = 960
ACTIVE = ("starting", "running")


@dataclass
class LiveView:
    """One live view and everything a page reads from it."""

    id: int
    source: str
    model_name: str
    model_dir: Path
    started_by: str
    smooth: bool
    mm_per_px: float | None
    travel_deg: float | None
    sequential: bool = False
    int8: bool = False
    model_id: int | None = None
    gate: dict[str, Any] | None = None
    """The version's promotion-gate verdict when the view started (usable, reason, …)."""
    started_at: dt.datetime = field(default_factory=utcnow)
    state: str = "starting"
    message: str = "opening the source"
    frames: int = 0
    dropped: int = 0
    records: collections.deque[dict[str, Any]] = field(
        default_factory=lambda: collections.deque(maxlen=KEEP_RECORDS)
    )
    latencies: collections.deque[float] = field(
        default_factory=lambda: collections.deque(maxlen=STATS_WINDOW)
    )
    stamps: collections.deque[float] = field(
        default_factory=lambda: collections.deque(maxlen=STATS_WINDOW)
    )
    jpeg: bytes | None = None
    jpeg_number: int = 0
    outputs: Any = None
    """The view's ``weldpool_core.cell.outputs.Outputs`` (ZeroMQ, OPC UA, MQTT), or None."""
    stop_event: threading.Event = field(default_factory=threading.Event)
    changed: threading.Condition = field(default_factory=threading.Condition)
    thread: threading.Thread | None = None

    def stats(self) -> dict[str, float | None]:
        """fps and p50 / p99 latency over the last frames."""
        stamps, latencies = list(self.stamps), list(self.latencies)
        fps = None
        if len(stamps) > 1 and stamps[-1] > stamps[0]:
            fps = (len(stamps) - 1) / (stamps[-1] - stamps[0])
        p50 = p99 = None
        if latencies:
            p50, p99 = (float(v) for v in np.percentile(latencies, [50, 99]))
        return {"fps": fps, "latency_p50_ms": p50, "latency_p99_ms": p99}

    def records_after(self, after: int, limit: int) -> list[dict[str, Any]]:
        """Kept records of frames after frame index ``after``, oldest first."""
        return [r for r in list(self.records) if r["frame"] > after][:limit]

    def next_jpeg(self, seen: int, timeout: float) -> tuple[int, bytes | None]:
        """The first overlay newer than number ``seen`` (waiting up to ``timeout``)."""
        with self.changed:
            self.changed.wait_for(
                lambda: self.jpeg_number > seen or self.state not in ACTIVE, timeout
            )
            return self.jpeg_number, self.jpeg


class LiveViews:
    """The live views of this process (see the module doc)."""

    def __init__(self) -> None:
        self._views: dict[int, LiveView] = {}
        self._ids = itertools.count(1)
        self._lock = threading.Lock()

    def start(self, view_args: dict[str, Any], outputs: Any = None) -> LiveView:
        """Start a view; 409 when ``MAX_RUNNING`` already run. ``outputs`` (an
        ``OutputsConfig``) are opened now, so a port in use is a 400 before anything runs."""
        from weldpool_core.cell.stream import parse_source

        parse_source(view_args["source"])  # a missing file is a 400 now, not a failed view
        with self._lock:
            running = [v for v in self._views.values() if v.state in ACTIVE]
            if len(running) >= MAX_RUNNING:
                raise ConflictError(
                    f"{len(running)} live views are running; stop one before starting another."
                )
        opened = _open_outputs(view_args, outputs)
        try:
            return self._register(view_args, opened)
        except BaseException:
            if opened is not None:
                opened.close()
            raise

    def _register(self, view_args: dict[str, Any], outputs: Any) -> LiveView:
        with self._lock:
            running = [v for v in self._views.values() if v.state in ACTIVE]
            if len(running) >= MAX_RUNNING:
                raise ConflictError(
                    f"{len(running)} live views are running; stop one before starting another."
                )
            view = LiveView(id=next(self._ids), outputs=outputs, **view_args)
            self._views[view.id] = view
            ended = [v.id for v in self._views.values() if v.state not in ACTIVE]
            for old in sorted(ended)[: max(0, len(ended) - KEEP_ENDED)]:
                del self._views[old]
        view.thread = threading.Thread(target=_run, args=(view,), name=f"live-{view.id}")
        view.thread.daemon = True
        view.thread.start()
        return view

    def get(self, view_id: int) -> LiveView:
        view = self._views.get(view_id)
        if view is None:
            raise NotFoundError(f"There is no live view {view_id}.")
        return view

    def all(self) -> list[LiveView]:
        return sorted(self._views.values(), key=lambda v: v.id, reverse=True)

    def stop(self, view_id: int) -> LiveView:
        """Ask a view to stop (it ends after its current frame)."""
        view = self.get(view_id)
        view.stop_event.set()
        if view.thread is not None:
            view.thread.join(timeout=10)
        return view

    def stop_all(self) -> None:
        for view in list(self._views.values()):
            view.stop_event.set()
        for view in list(self._views.values()):
            if view.thread is not None:
                view.thread.join(timeout=10)


MIN_PORT = 1024
"""The live view listens on no privileged port (nor on one below it that a service may own)."""


def _listed(value: str) -> set[str]:
    return {part.strip().lower() for part in value.split(",") if part.strip()}


def check_outputs(zeromq: str | None, opcua: str | None, mqtt: str | None, settings: Any) -> None:
    """Refuse live-view outputs outside what the admin allows (``live_bind_hosts``,
    ``live_mqtt_brokers``): a reviewer's form must not bind any address of the server, reach any
    host, or give ZeroMQ a path (``ipc://`` replaces the file there)."""
    from urllib.parse import urlparse

    from weldpool_core.cell.outputs.mqtt import parse_mqtt_url
    from weldpool_core.cell.outputs.opcua import parse_opcua_url

    binds = _listed(settings.live_bind_hosts)
    allowed = ", ".join(sorted(binds)) or "none"
    where = (
        f"(WELDPOOL_LIVE_BIND_HOSTS: {allowed}); ask an admin, or run weldpool stream at the cell"
    )
    listens: list[tuple[str, str, int | None]] = []
    if zeromq:
        parsed = urlparse(zeromq)
        try:
            port = parsed.port
        except ValueError:
            port = None
        if parsed.scheme != "tcp" or not parsed.hostname or port is None or parsed.path:
            raise InvalidInputError(
                f"The live view's ZeroMQ output takes tcp://HOST:PORT only, not {zeromq!r}."
            )
        listens.append(("ZeroMQ", parsed.hostname, port))
    if opcua:
        host, port = parse_opcua_url(opcua)
        listens.append(("OPC UA", host, port))
    for name, host, port in listens:
        if host.lower() not in binds:
            raise InvalidInputError(
                f"The live view's {name} output may not listen on {host} {where}."
            )
        if port is not None and port < MIN_PORT:
            raise InvalidInputError(f"The live view's {name} port must be {MIN_PORT} or above.")
    if mqtt:
        target = parse_mqtt_url(mqtt)
        brokers = _listed(settings.live_mqtt_brokers)
        if target.host.lower() not in brokers:
            raise InvalidInputError(
                f"The live view may not publish to the broker {target.host} "
                f"(WELDPOOL_LIVE_MQTT_BROKERS: {', '.join(sorted(brokers)) or 'none'})."
            )


def _open_outputs(view_args: dict[str, Any], config: Any) -> Any:
    """The view's outputs, opened (None when it has none)."""
    if config is None or not config.any():
        return None
    from weldpool_core.cell.outputs import CellInfo, open_outputs
    from weldpool_core.student.checkpoint import read_student_config

    gate = view_args.get("gate") or {}
    student = read_student_config(view_args["model_dir"])
    info = CellInfo(
        model=view_args["model_name"],
        keypoints=student.k,
        mm_per_px=view_args.get("mm_per_px"),
        model_usable=gate.get("usable") is not False,
        classes=tuple(student.classes),  # the view's stream adds every learned class
    )
    return open_outputs(config, info)


def _set(view: LiveView, **changes: Any) -> None:
    with view.changed:
        for name, value in changes.items():
            setattr(view, name, value)
        view.changed.notify_all()


def _set_message(view: LiveView, message: str) -> None:
    _set(view, message=message)


def _run(view: LiveView) -> None:
    """The view's thread: open, stream, keep the newest overlay and records."""
    try:
        from weldpool_core.cell.smoothing import SmoothingParams
        from weldpool_core.cell.stream import StreamOptions, open_stream

        options = StreamOptions(
            sequential=view.sequential,
            int8=view.int8,
            smoothing=SmoothingParams() if view.smooth else None,
            mm_per_px=view.mm_per_px,
            travel_deg=view.travel_deg,
            realtime=True,
            decoder_threads=1,
        )
        status = partial(_set_message, view)
        with open_stream(
            view.source, view.model_dir, options, status=status, stop=view.stop_event
        ) as results:
            _set(view, state="running", message="")
            drawn = 0.0
            for result in results:
                record = result.record
                if view.outputs is not None:
                    view.outputs.send(record)
                view.records.append(record)
                view.latencies.append(record["latency_ms"])
                view.stamps.append(time.perf_counter())
                view.frames += 1
                view.dropped += record["dropped"]
                now = time.perf_counter()
                if now - drawn >= 1.0 / OVERLAY_FPS:
                    drawn = now
                    jpeg = overlay_jpeg(result)
                    _set(view, jpeg=jpeg, jpeg_number=view.jpeg_number + 1)
        if view.stop_event.is_set():
            _set(view, state="stopped", message="stopped")
        else:
            _set(view, state="ended", message="the source ended")
    except WeldpoolError as exc:
        _set(view, state="failed", message=exc.message)
    except Exception:
        log.exception("live.crashed", view=view.id)
        _set(view, state="failed", message="Internal error; the server log has the details.")
    finally:
        if view.outputs is not None:
            view.outputs.close()


def overlay_jpeg(result: Any) -> bytes:
    """The frame, at most ``OVERLAY_WIDTH`` wide, with the mask outline and keypoints drawn."""
    bgr = result.frame.bgr
    height, width = bgr.shape[:2]
    factor = min(1.0, OVERLAY_WIDTH / width)
    size = (max(1, round(width * factor)), max(1, round(height * factor)))
    shown = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA) if factor < 1 else bgr.copy()
    geometry = result.geometry
    inner = result.mask_probability[geometry.inner_rows, geometry.inner_columns]
    mask = cv2.resize((inner >= 0.5).astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(shown, contours, -1, (80, 220, 255), 2, cv2.LINE_AA)
    for number, point in enumerate(result.keypoints, start=1):
        if point is None:
            continue
        centre = (round((point[0] + 0.5) * factor - 0.5), round((point[1] + 0.5) * factor - 0.5))
        cv2.circle(shown, centre, 6, (40, 40, 255), -1, cv2.LINE_AA)
        right = centre[0] + 24 > size[0]  # near the right edge: the number goes to the left
        cv2.putText(
            shown,
            str(number),
            (centre[0] - 22 if right else centre[0] + 8, max(14, centre[1] - 8)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.6,
            (255, 255, 255),
            2,
            cv2.LINE_AA,
        )
    ok, encoded = cv2.imencode(".jpg", shown, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return encoded.tobytes() if ok else b""
