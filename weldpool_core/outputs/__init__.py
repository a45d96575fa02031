"""Where the stream's records go in a welding cell: ZeroMQ, OPC UA and MQTT.

Every output takes each record with ``send`` and never blocks the inference thread: the OPC UA
server and the MQTT client run on threads of their own and take the newest record when they are
ready (a slow network or a flooding client makes them skip frames, never delay the next one).
``status()`` says what a live view shows: the state, the subscriber count where the protocol
knows it, frames sent and skipped, and the time ``send`` → on the wire (``added_ms``).

``CellRecord`` is the one rule for what a PLC or a dashboard reads: the record's values under
the names and units the OPC UA variables and the MQTT messages share (``CELL_FIELDS``).
Problems (a broker gone, a subscriber that stops reading, a server that falls behind) are
logged once when they start and once when they end (``Reporter``).
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

log = logging.getLogger("weldpool.outputs")

STALE_MS = 500.0
"""No frame for this long: the outputs say the stream is not healthy (``--stale-ms``)."""
KEEP_LATENCIES = 2000


@dataclass(frozen=True)
class CellField:
    """One value the cell reads: its OPC UA browse name, MQTT key, unit and meaning."""

    name: str
    key: str
    unit: str
    description: str


CELL_FIELDS: tuple[CellField, ...] = (
    CellField("FrameCounter", "frame", "", "The frame's number in the source (gaps: dropped)."),
    CellField("CaptureTime", "t", "s", "When the frame was captured (Unix time)."),
    CellField("Area", "area", "{length}²", "Pool area."),
    CellField("Length", "length", "{length}", "Pool length along the travel direction."),
    CellField("Width", "width", "{length}", "Pool width across the travel direction."),
    CellField(
        "StabilityCV",
        "stability_cv",
        "",
        "The width's rolling coefficient of variation over the last 0.5 s (NaN: under 3 frames).",
    ),
    CellField("Unstable", "unstable", "", "True while that variation is over 8 %."),
    CellField("CentroidX", "cx", "px", "Pool centroid, frame column."),
    CellField("CentroidY", "cy", "px", "Pool centroid, frame row."),
    CellField(
        "Keypoints",
        "keypoints",
        "px",
        "Keypoints as x1, y1, x2, y2, … in frame pixels (NaN: none).",
    ),
    CellField(
        "Uncertainty",
        "uncertainty",
        "",
        "The student's uncertainty, 0..1 (NaN when the stream does not draw samples).",
    ),
    CellField("Ambiguity", "ambiguity", "", "Mask probability in doubt relative to the area."),
    CellField("LatencyMs", "latency_ms", "ms", "Capture to record, milliseconds."),
    CellField("Healthy", "healthy", "", "True while frames arrive and the model is usable."),
)


@dataclass(frozen=True)
class CellInfo:
    """What every output knows of the run before its first frame."""

    model: str
    keypoints: int
    mm_per_px: float | None = None
    model_usable: bool = True
    """False for a student the promotion gate found worse than the teacher (forced)."""
    stale_ms: float = STALE_MS

    @property
    def length_unit(self) -> str:
        return "mm" if self.mm_per_px else "px"

    def unit(self, spec: CellField) -> str:
        return spec.unit.format(length=self.length_unit)


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


@dataclass(frozen=True)
class CellRecord:
    """A record in the cell's terms (see ``CELL_FIELDS``): millimetres when the run has a scale."""

    frame: int
    t: float
    area: float
    length: float
    width: float
    stability_cv: float
    unstable: bool
    cx: float
    cy: float
    keypoints: tuple[float, ...]
    uncertainty: float
    ambiguity: float
    latency_ms: float
    healthy: bool

    @classmethod
    def of(cls, record: dict[str, Any], info: CellInfo) -> CellRecord:
        unit = info.length_unit  # the values in the units the variables declare
        area = record["area_mm2" if unit == "mm" else "area_px"]
        length, width = record[f"length_{unit}"], record[f"width_{unit}"]
        centroid = record.get("centroid") or (None, None)
        flat: list[float] = []
        for point in record.get("keypoints") or [None] * info.keypoints:
            flat += [math.nan, math.nan] if point is None else [float(point[0]), float(point[1])]
        return cls(
            frame=int(record["frame"]),
            t=float(record["captured_at"]),
            area=_number(area),
            length=_number(length),
            width=_number(width),
            stability_cv=_number(record.get("stability_cv")),
            unstable=bool(record.get("unstable")),
            cx=_number(centroid[0]),
            cy=_number(centroid[1]),
            keypoints=tuple(flat),
            uncertainty=_number(record.get("uncertainty")),
            ambiguity=_number(record.get("ambiguity")),
            latency_ms=_number(record.get("latency_ms")),
            healthy=info.model_usable,
        )

    def message(self) -> dict[str, Any]:
        """The compact JSON form (MQTT): NaN becomes null, keypoints pairs."""

        def clean(value: float) -> float | None:
            return None if math.isnan(value) else round(value, 3)

        pairs = [
            None if math.isnan(x) else [round(x, 2), round(y, 2)]
            for x, y in zip(self.keypoints[::2], self.keypoints[1::2], strict=True)
        ]
        return {
            "frame": self.frame,
            "t": round(self.t, 6),
            "area": clean(self.area),
            "length": clean(self.length),
            "width": clean(self.width),
            "stability_cv": clean(self.stability_cv),
            "unstable": self.unstable,
            "cx": clean(self.cx),
            "cy": clean(self.cy),
            "keypoints": pairs,
            "uncertainty": clean(self.uncertainty),
            "ambiguity": clean(self.ambiguity),
            "latency_ms": clean(self.latency_ms),
            "healthy": self.healthy,
        }


@dataclass
class OutputStatus:
    """What a live view shows of one output."""

    kind: str
    address: str
    state: str
    subscribers: int | None
    sent: int
    skipped: int
    added_p50_ms: float | None = None
    added_p99_ms: float | None = None


class Output(Protocol):
    """What every output does (``stale`` and ``resumed``, where an output has them, are told by
    ``Outputs``' watchdog)."""

    kind: str
    address: str

    def send(self, record: dict[str, Any]) -> None: ...

    def wait_for_subscriber(self, seconds: float) -> bool: ...

    def status(self) -> OutputStatus: ...

    def close(self) -> None: ...


class Reporter:
    """Logs a problem once when it starts and once when it ends (not once per frame)."""

    def __init__(self, output: str) -> None:
        self.output = output
        self._open: set[str] = set()
        self._lock = threading.Lock()

    def problem(self, key: str, message: str) -> None:
        with self._lock:
            if key in self._open:
                return
            self._open.add(key)
        log.warning("%s: %s", self.output, message)

    def resolved(self, key: str, message: str) -> None:
        with self._lock:
            if key not in self._open:
                return
            self._open.discard(key)
        log.warning("%s: %s", self.output, message)


@dataclass
class Counters:
    """Frames sent and skipped by one output, and its added latency (``send`` → wire)."""

    sent: int = 0
    skipped: int = 0
    added_ms: collections.deque[float] = field(
        default_factory=lambda: collections.deque(maxlen=KEEP_LATENCIES)
    )

    def added(self, since: float) -> None:
        self.sent += 1
        self.added_ms.append(1000.0 * (time.perf_counter() - since))

    def percentiles(self) -> tuple[float | None, float | None]:
        values = sorted(self.added_ms)
        if not values:
            return None, None
        return _percentile(values, 50), _percentile(values, 99)


def _percentile(values: list[float], q: float) -> float:
    position = (len(values) - 1) * q / 100
    low = math.floor(position)
    high = min(low + 1, len(values) - 1)
    return round(values[low] + (values[high] - values[low]) * (position - low), 4)


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


@dataclass(frozen=True)
class OutputsConfig:
    """Which outputs a stream opens (``weldpool stream`` options, the live view's form)."""

    zeromq: str | None = None
    opcua: Any = None
    """``opcua.OpcUaOptions`` or None."""
    mqtt: Any = None
    """``mqtt.MqttOptions`` or None."""

    def any(self) -> bool:
        return bool(self.zeromq or self.opcua or self.mqtt)


def open_outputs(config: OutputsConfig, info: CellInfo) -> Outputs:
    """Open each configured output (one-sentence ``InvalidInputError`` for a bad address, a port
    in use or a broker host that does not resolve); what opened is closed again on a failure."""
    opened: list[Any] = []
    try:
        if config.zeromq:
            from weldpool_core.outputs.zmq import Publisher

            opened.append(Publisher(config.zeromq))
        if config.opcua is not None:
            from weldpool_core.outputs.opcua import OpcUaServer

            opened.append(OpcUaServer(config.opcua, info))
        if config.mqtt is not None:
            from weldpool_core.outputs.mqtt import MqttPublisher, check_broker_host

            check_broker_host(config.mqtt.url)
            opened.append(MqttPublisher(config.mqtt, info))
    except BaseException:
        Outputs(opened, info).close()  # each closed, even when one of them fails to
        raise
    return Outputs(opened, info)
