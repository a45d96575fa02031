"""The student beside the robot: frames from a camera or a video in, keypoints and geometry out.

``FrameSource`` reads a video file, a camera index or a network URL (OpenCV) on its own thread.
A live source (camera, URL, or a file read with ``realtime=True``, paced at its frame rate)
keeps only the newest frame: when inference falls behind, older frames are dropped and counted,
so the output is never later than one frame plus its own work (no queue grows). A file read as
fast as possible delivers every frame in order (a queue of two).

``StreamStudent`` runs a trained student on one frame at a time: ONNX Runtime by default (the
``model.onnx`` of ``weldpool export-student``; ``int8=True`` runs its ``model.int8.onnx``, the
quantized student, ``student.quantize``), PyTorch as an option (CUDA when present, and the
only backend that can score the uncertainty, which draws the latent and reads the encoder). With
``sequential=True`` it runs the folder's sequential student instead (``student.sequential``: a
recurrent cell on the latent, trained with ``weldpool train-sequential``), carrying its state
from one delivered frame to the next; ``reset()`` starts a new stream.

``run_stream`` joins them: per frame one ``StreamResult`` whose ``record`` is what a controller
reads (``record_fields``): capture time, frame index, keypoints in frame pixels, pool area,
length, width and centroid (pixels, and millimetres with a scale), the width's rolling
stability (``stability_cv``, ``unstable``: ``signature.RollingStability``), ambiguity, uncertainty,
frames dropped before it, the latency from capture to the record, and for a student that
learned other classes beside the pool their geometry (``classes``: ``cell.class_geometry``; null
for a pool-only student or when none is asked for). Geometry is measured on
the model's mask placed in frame pixels (``geometry.pool_shape`` with origin and pixel size), so
no full-resolution mask is made per frame. ``ambiguity`` is cheap and always there: the mask
probability in doubt, Σ 2·min(p, 1 − p), relative to the pool's area (0 for a crisp mask; high
where the student hesitates about the boundary; ``predict.mask_ambiguity``, the rule the
uncertainty's ambiguity part uses on the latent draws' mean).

The records go to a controller through ``weldpool_core.cell.outputs``: ZeroMQ (``Publisher``),
OPC UA and MQTT.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from weldpool_core.cell.class_geometry import chosen_classes, class_geometry
from weldpool_core.cell.smoothing import KeypointSmoother, SmoothingParams
from weldpool_core.errors import InvalidInputError
from weldpool_core.geometry import pool_shape
from weldpool_core.signature import RollingStability
from weldpool_core.student.checkpoint import ONNX_FILE, read_student_config
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.export import ensure_onnx
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import frame_keypoints, mask_ambiguity
from weldpool_core.student.runners import RunnerOptions, open_runner, runner_kind

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

NETWORK_SCHEMES = ("rtsp", "rtsps", "rtmp", "http", "https", "udp", "tcp", "srt")
OPEN_TIMEOUT_MS = 5000
"""How long opening (or reading) a network stream may take before it counts as unreachable."""
_END = object()


@dataclass(frozen=True)
class CapturedFrame:
    """One frame as the source gave it.

    Attributes:
        index: the frame's number in the source, counting dropped frames (so gaps show).
        wall_time: Unix time at capture, seconds.
        captured: ``time.perf_counter()`` at capture, for the latency. A file read frame by
            frame has no capture: its frames are "captured" when the pipeline takes them.
        time_s: the frame's time in the source, seconds: index / fps for a file (so filters
            see the recording's time steps however fast it is read), else since the first
            frame was read.
        bgr: H×W×3 uint8 in OpenCV's BGR order, as decoded (a live view encodes it as is).
        prepared: what the source's ``prepare`` made of it on the reader thread (the model's
            input), or None.
        dropped: frames dropped between the previous delivered frame and this one.
    """

    index: int
    wall_time: float
    captured: float
    bgr: NDArray[np.uint8]
    prepared: Any = None
    dropped: int = 0
    time_s: float = 0.0


def parse_source(source: str) -> tuple[str | int, bool]:
    """OpenCV's argument for SOURCE, and whether it is live (a camera index or a network URL).

    Raises InvalidInputError for a path that does not exist.
    """
    text = source.strip()
    if text.isdigit():
        return int(text), True
    scheme = text.split("://", 1)[0].lower() if "://" in text else ""
    if scheme in NETWORK_SCHEMES:
        return text, True
    if scheme == "file":
        text = text.split("://", 1)[1]
    if not Path(text).is_file():
        raise InvalidInputError(
            f"There is no video file {text!r}; give a file, a camera index (0, 1, …) or a URL "
            f"({', '.join(NETWORK_SCHEMES[:3])}, …)."
        )
    return text, False


class FrameSource:
    """Frames of a video file, camera or URL, read on a thread (see the module doc).

    Args:
        source: a path, a camera index ("0") or a URL.
        realtime: read a file at its own frame rate and drop stale frames, as a camera would.
        max_frames: stop after this many frames read (None: until the source ends).
        prepare: called on each BGR frame on the reader thread (the model's pre-processing,
            which then overlaps with inference); its result is the frame's ``prepared``.
        decoder_threads: threads of the video decoder (None: OpenCV's default, one per core).
    """

    def __init__(
        self,
        source: str,
        realtime: bool = False,
        max_frames: int | None = None,
        prepare: Callable[[NDArray[np.uint8]], Any] | None = None,
        decoder_threads: int | None = None,
    ) -> None:
        argument, live = parse_source(source)
        options: list[int] = []
        if isinstance(argument, str) and live:  # a network stream: do not hang on a dead host
            options += [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, OPEN_TIMEOUT_MS]
            options += [cv2.CAP_PROP_READ_TIMEOUT_MSEC, OPEN_TIMEOUT_MS]
        if decoder_threads:
            options += [cv2.CAP_PROP_N_THREADS, decoder_threads]
        capture = cv2.VideoCapture(argument, cv2.CAP_ANY, options)
        if not capture.isOpened():
            raise InvalidInputError(
                f"OpenCV cannot open {source!r} as a video source (not a video it can decode, "
                "no such camera, or the stream is unreachable)."
            )
        self._capture = capture
        fps = capture.get(cv2.CAP_PROP_FPS)
        self.fps: float | None = float(fps) if fps and math.isfinite(fps) and fps > 0 else None
        self.live = live or realtime
        self.realtime = realtime and not live
        self.max_frames = max_frames
        self.prepare = prepare
        self.read_count = 0
        self.dropped = 0
        self._stop = threading.Event()
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=2)
        self._latest: Any = None
        self._dropped_since = 0
        self._ended = False
        self._error: BaseException | None = None
        self._ready = threading.Condition()
        self._started = time.perf_counter()
        self._thread = threading.Thread(target=self._read, name="frame-source", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        period = 1.0 / self.fps if self.realtime and self.fps else None
        start = time.perf_counter()
        try:
            while not self._stop.is_set():
                if self.max_frames is not None and self.read_count >= self.max_frames:
                    break
                if period is not None:
                    delay = start + self.read_count * period - time.perf_counter()
                    if delay > 0:
                        time.sleep(delay)
                ok, frame = self._capture.read()
                if not ok or frame is None:
                    break
                captured, wall = time.perf_counter(), time.time()
                bgr = _bgr(frame)
                prepared = None if self.prepare is None else self.prepare(bgr)
                item = (self.read_count, wall, captured, bgr, prepared)
                self.read_count += 1
                if self.live:
                    with self._ready:
                        if self._latest is not None:
                            self._dropped_since += 1
                            self.dropped += 1
                        self._latest = item
                        self._ready.notify()
                else:
                    while not self._stop.is_set():
                        try:
                            self._queue.put(item, timeout=0.1)
                            break
                        except queue.Full:
                            continue
        except Exception as exc:  # handed to the consumer, which raises it
            self._error = exc
        finally:
            self._capture.release()
            with self._ready:
                self._ended = True
                self._ready.notify()
            while not self.live and not self._stop.is_set():
                try:
                    self._queue.put(_END, timeout=0.1)
                    break
                except queue.Full:
                    continue

    def __iter__(self) -> Iterator[CapturedFrame]:
        while not self._stop.is_set():
            if self.live:
                with self._ready:
                    while self._latest is None and not self._ended:
                        self._ready.wait(0.1)
                    if self._latest is None:
                        self._raise_error()
                        return
                    item, self._latest = self._latest, None
                    dropped, self._dropped_since = self._dropped_since, 0
            else:
                item = self._queue.get()
                if item is _END:
                    self._raise_error()
                    return
                dropped = 0
            index, wall, captured, bgr, prepared = item
            if self.live:
                time_s = captured - self._started
            else:
                wall, captured = time.time(), time.perf_counter()
                time_s = index / self.fps if self.fps else captured - self._started
            yield CapturedFrame(index, wall, captured, bgr, prepared, dropped, time_s)

    def _raise_error(self) -> None:
        """Raise what stopped the reader thread, if anything did."""
        if self._error is not None:
            raise self._error

    def close(self) -> None:
        """Stop reading and release the source."""
        self._stop.set()
        with self._ready:
            self._ready.notify_all()
        while True:  # unblock a reader waiting on a full queue
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        self._thread.join(timeout=5.0)

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _bgr(frame: NDArray[Any]) -> NDArray[np.uint8]:
    """OpenCV's frame as H×W×3 BGR uint8 (gray repeated, alpha dropped, 16-bit scaled)."""
    if frame.dtype == np.uint16:
        frame = (frame >> 8).astype(np.uint8)
    if frame.ndim == 2:
        return np.ascontiguousarray(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    return np.ascontiguousarray(frame[:, :, :3], dtype=np.uint8)


class StreamStudent:
    """A trained student for one frame at a time (see the module doc): the runner of its kind
    (``student.runners``) and the frame preparation they share.

    Args:
        model_dir: the student's folder.
        backend: "onnx" (ONNX Runtime on the CPU; needs ``model.onnx``) or "torch".
        device: for torch: cpu, cuda, cuda:N, mps or auto.
        threads: intra-op threads (None: the runtime's default, one per core). For torch this
            is ``torch.set_num_threads``: it holds for the whole process.
        spin: let ONNX Runtime's idle threads busy-wait (see ``onnx_session``).
        sequential: run the folder's sequential student (see the module doc).
        int8: run the folder's ``model.int8.onnx`` (ONNX Runtime, per frame only).
    """

    def __init__(
        self,
        model_dir: str | Path,
        backend: str = "onnx",
        device: str = "auto",
        threads: int | None = None,
        spin: bool = False,
        sequential: bool = False,
        int8: bool = False,
    ) -> None:
        self.kind = runner_kind(backend, sequential, int8)
        self.model_dir = Path(model_dir)
        self.config: StudentConfig = read_student_config(self.model_dir)
        self.backend = backend
        self.sequential = sequential
        self.int8 = int8
        options = RunnerOptions(self.model_dir, self.config, backend, device, threads, spin)
        self._runner = open_runner(options, self.kind)

    def reset(self) -> None:
        """Forget the sequential student's state: the next frame starts a new stream."""
        self._runner.reset()

    def prepare(self, bgr: NDArray[np.uint8]) -> tuple[NDArray[np.float32], FrameGeometry]:
        """A BGR frame → the 1×3×S×S RGB input in [0, 1], and its geometry (resized first,
        then converted: the colour conversion runs on the small image)."""
        config = self.config
        geometry = FrameGeometry.fit(bgr.shape[0], bgr.shape[1], config.input_size, config.aspect)
        fitted = cv2.cvtColor(geometry.image_to_input(bgr), cv2.COLOR_BGR2RGB)
        batch = np.ascontiguousarray(fitted.transpose(2, 0, 1)[None], dtype=np.float32)
        batch *= 1.0 / 255.0
        return batch, geometry

    def __call__(
        self, batch: NDArray[np.float32], geometry: FrameGeometry, samples: int = 0
    ) -> tuple[NDArray[np.float32], NDArray[np.float32], float | None]:
        """Mask probability and heatmap (S×S) of one prepared frame, and its uncertainty with
        ``samples`` > 0 (torch only, per-frame student only)."""
        return self._runner.run(batch, geometry, samples)

    @property
    def extra(self) -> NDArray[np.float32] | None:
        """The last frame's learned-class probabilities (E×S×S; None without classes)."""
        return self._runner.extra


@dataclass(frozen=True)
class StreamResult:
    """One frame's answer: the record for the controller, and what a live view draws."""

    record: dict[str, Any]
    frame: CapturedFrame
    mask_probability: NDArray[np.float32] = field(repr=False)
    geometry: FrameGeometry = field(repr=False)
    keypoints: list[list[float] | None] = field(default_factory=list)


def record_fields() -> tuple[str, ...]:
    """The keys of every record, in order (docs/guides/live.md documents each)."""
    return (
        "frame",
        "captured_at",
        "time_s",
        "keypoints",
        "keypoints_raw",
        "area_px",
        "length_px",
        "width_px",
        "centroid",
        "travel_deg",
        "area_mm2",
        "length_mm",
        "width_mm",
        "stability_cv",
        "unstable",
        "ambiguity",
        "uncertainty",
        "dropped",
        "latency_ms",
        "classes",
    )


def _rounded(values: Any, digits: int = 2) -> Any:
    if values is None:
        return None
    if isinstance(values, float):
        return round(values, digits)
    return [_rounded(v, digits) for v in values]


def analyse(
    frame: CapturedFrame,
    mask_probability: NDArray[np.float32],
    heatmap: NDArray[np.float32],
    geometry: FrameGeometry,
    config: StudentConfig,
    *,
    uncertainty: float | None = None,
    smoother: KeypointSmoother | None = None,
    mm_per_px: float | None = None,
    travel_deg: float | None = None,
    stability: RollingStability | None = None,
) -> StreamResult:
    """One frame's record from the student's S×S outputs (see ``record_fields``); with
    ``stability``, the width's rolling coefficient of variation (``signature.RollingStability``:
    the run signature's rule over the last ``window_s``) and whether it is over the unstable
    threshold."""
    raw = frame_keypoints(mask_probability, heatmap, geometry, config)
    inner = mask_probability[geometry.inner_rows, geometry.inner_columns]
    sx, sy = geometry.scale_x, geometry.scale_y
    shape = pool_shape(
        inner >= 0.5, origin=(0.5 / sx - 0.5, 0.5 / sy - 0.5), pixel=(1 / sx, 1 / sy)
    )
    pool = shape.measure(travel_deg)
    raw_list: list[list[float] | None] = [[float(x), float(y)] for x, y in raw]
    keypoints = raw_list if smoother is None else smoother.update(raw, frame.time_s)
    cv = None if stability is None else stability.update(frame.time_s, pool.width_px)
    record: dict[str, Any] = {
        "frame": frame.index,
        "captured_at": round(frame.wall_time, 6),
        "time_s": round(frame.time_s, 4),
        "keypoints": _rounded(keypoints),
        "keypoints_raw": _rounded(raw_list) if smoother is not None else None,
        "area_px": pool.area_px,
        "length_px": _rounded(pool.length_px),
        "width_px": _rounded(pool.width_px),
        "centroid": _rounded(list(pool.centroid)) if pool.centroid else None,
        "travel_deg": _rounded(pool.travel_deg),
        **{key: _rounded(value, 4) for key, value in pool.in_mm(mm_per_px).items()},
        "stability_cv": None if cv is None else round(cv, 4),
        "unstable": stability is not None and stability.unstable(cv),
        "ambiguity": round(mask_ambiguity(inner), 4),
        "uncertainty": None if uncertainty is None else round(uncertainty, 4),
        "dropped": frame.dropped,
        "latency_ms": None,
        "classes": None,
    }
    return StreamResult(record, frame, mask_probability, geometry, keypoints)


def run_stream(
    source: FrameSource,
    student: StreamStudent,
    *,
    smoother: KeypointSmoother | None = None,
    mm_per_px: float | None = None,
    travel_deg: float | None = None,
    samples: int = 0,
    stop: threading.Event | None = None,
    classes: tuple[str, ...] | None = None,
) -> Iterator[StreamResult]:
    """The student on every delivered frame of ``source``; each record ends with its latency
    and carries the width's rolling stability (``analyse``) and the geometry of the learned
    ``classes`` (None: every class the student learned; ``cell.class_geometry``)."""
    stability = RollingStability()
    learned = student.config.classes
    chosen = chosen_classes(learned, classes)
    for frame in source:
        if stop is not None and stop.is_set():
            return
        batch, geometry = frame.prepared or student.prepare(frame.bgr)
        mask, heatmap, uncertainty = student(batch, geometry, samples)
        result = analyse(
            frame,
            mask,
            heatmap,
            geometry,
            student.config,
            uncertainty=uncertainty,
            smoother=smoother,
            mm_per_px=mm_per_px,
            travel_deg=travel_deg,
            stability=stability,
        )
        extra = student.extra
        if chosen and extra is not None:
            result.record["classes"] = class_geometry(extra, learned, chosen, geometry)
        result.record["latency_ms"] = round(1000.0 * (time.perf_counter() - frame.captured), 3)
        yield result


@dataclass(frozen=True)
class StreamOptions:
    """How ``open_stream`` runs a student on a source (``weldpool stream`` and the live view).

    ``backend``, ``device``, ``threads``, ``sequential`` and ``int8`` choose the runner
    (``StreamStudent``); ``smoothing`` the keypoints' One-Euro filter (None: raw keypoints);
    ``mm_per_px`` and ``travel_deg`` the record's millimetres and travel direction;
    ``samples`` the uncertainty's latent draws (the per-frame student on PyTorch only);
    ``realtime``, ``max_frames`` and ``decoder_threads`` how the source is read
    (``FrameSource``); ``classes`` the learned classes whose geometry each record adds (None:
    all the student learned; ``()``: none).
    """

    backend: str = "onnx"
    device: str = "auto"
    threads: int | None = None
    sequential: bool = False
    int8: bool = False
    smoothing: SmoothingParams | None = None
    mm_per_px: float | None = None
    travel_deg: float | None = None
    samples: int = 0
    realtime: bool = False
    max_frames: int | None = None
    decoder_threads: int | None = None
    classes: tuple[str, ...] | None = None


def _silent(_message: str) -> None:
    pass


@contextmanager
def open_stream(
    source: str,
    model_dir: str | Path,
    options: StreamOptions,
    *,
    status: Callable[[str], None] = _silent,
    stop: threading.Event | None = None,
) -> Iterator[Iterator[StreamResult]]:
    """The whole pipeline, opened: the student's ONNX file exported if it is missing (with a
    ``status`` message, as is the sequential student's), the runner, the keypoint smoother and
    the source; yields the results as ``run_stream`` makes them, and closes the source at the
    end of the block."""
    root = Path(model_dir)
    kind = runner_kind(options.backend, options.sequential, options.int8)
    if options.samples and kind != "torch":
        raise InvalidInputError("The uncertainty needs the per-frame student on PyTorch.")
    if kind == "onnx" and not (root / ONNX_FILE).is_file():
        status(f"exporting {ONNX_FILE} for ONNX Runtime")
        ensure_onnx(root)
    if kind == "sequential" and options.backend == "onnx":
        status("preparing the sequential student for ONNX Runtime")
    student = StreamStudent(
        root,
        options.backend,
        options.device,
        options.threads,
        sequential=options.sequential,
        int8=options.int8,
    )
    smoother = None
    if options.smoothing is not None:
        smoother = KeypointSmoother(student.config.k, options.smoothing)
    with FrameSource(
        source,
        realtime=options.realtime,
        max_frames=options.max_frames,
        prepare=student.prepare,
        decoder_threads=options.decoder_threads,
    ) as frames:
        yield run_stream(
            frames,
            student,
            smoother=smoother,
            mm_per_px=options.mm_per_px,
            travel_deg=options.travel_deg,
            samples=options.samples,
            stop=stop,
            classes=options.classes,
        )


def summary(latencies_ms: list[float], frames: int, dropped: int, seconds: float) -> dict[str, Any]:
    """Frames, drops, fps and p50 / p99 latency of a finished stream."""
    values = np.asarray(latencies_ms, np.float64)
    return {
        "frames": frames,
        "dropped": dropped,
        "fps": round(frames / seconds, 2) if seconds > 0 else None,
        "latency_p50_ms": round(float(np.percentile(values, 50)), 3) if len(values) else None,
        "latency_p99_ms": round(float(np.percentile(values, 99)), 3) if len(values) else None,
    }
