"""The terms every output of the stream shares: ``CellRecord``, the one rule for what a PLC or
a dashboard reads (the record's values under the names and units the OPC UA variables and the
MQTT messages share, ``CELL_FIELDS``); ``CellInfo``, what an output knows before the first
frame; ``OutputStatus`` and ``Counters``, what a live view shows of one; ``Reporter``, which
logs a problem once when it starts and once when it ends; and the ``Output`` protocol."""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from weldpool_core.student.classes import LearnedClass

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
    classes: tuple[LearnedClass, ...] = ()
    """The learned classes whose geometry the records carry (``cell.class_geometry.chosen_classes``
    of ``--classes``): the OPC UA server makes their variables before the first frame."""

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
    classes: dict[str, Any] | None = None
    """The learned classes' geometry (``cell.class_geometry``): in the MQTT message, and in the
    OPC UA variables under ``WeldPool.Classes`` (``outputs.opcua_classes``)."""

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
            classes=record.get("classes"),
        )

    def message(self) -> dict[str, Any]:
        """The compact JSON form (MQTT): NaN becomes null, keypoints pairs, and the learned
        classes' geometry under ``classes`` when the student has any."""

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
        } | ({} if self.classes is None else {"classes": self.classes})


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
