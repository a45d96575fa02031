"""An int8 student for a CPU beside the robot: ONNX Runtime's static quantization, checked.

``quantize_student`` turns a folder's ``model.onnx`` into ``model.int8.onnx``: weights int8
per output channel (in 7 bits, so that CPUs without VNNI do not saturate), activations uint8
(QDQ format, which ONNX Runtime runs with its integer kernels: VNNI where the CPU has it), the
activations' ranges calibrated on real frames of the user's own camera. Random frames would
calibrate the wrong ranges, so frames are required.

Frames alternate between calibration and check: the int8 model is measured against the float
one on frames it was not calibrated on — the mask IoU at the 0.5 threshold on each frame's
image area (not the letterbox padding) and the keypoints' distance — and kept only when the
masks agree (mean IoU ≥ ``MIN_MEAN_IOU`` and every frame ≥ ``MIN_FRAME_IOU``); otherwise
nothing is written (an earlier int8 file stays) and the error gives the figures. The record,
with one frame's time through each file on this machine, lands in ``export.json`` under
``int8``. ``weldpool stream --int8`` and ``StreamStudent(int8=True)`` run it.

Importing this module loads neither torch nor ONNX Runtime (its functions do), so a web process
can read its names.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError
from weldpool_core.metrics import iou
from weldpool_core.student import checkpoint
from weldpool_core.student.checkpoint import (
    EXPORT_FILE,
    INT8_ONNX_FILE,
    ONNX_FILE,
    weights_digest,
)

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

if TYPE_CHECKING:
    from weldpool_core.student.data import FrameGeometry
    from weldpool_core.student.model import StudentConfig

MIN_FRAMES = 4
"""Frames needed: half calibrate, half check."""
MIN_MEAN_IOU = 0.97
"""The int8 masks' mean IoU with the float ones on the check frames, at least."""
MIN_FRAME_IOU = 0.90
"""…and on every check frame."""
TIMING_RUNS = 15


WORK_PREFIX = ".quantize."
"""The quantizer's work folder in MODEL_DIR (removed when it ends, unless its process dies)."""


def remove_leftovers(model_dir: str | Path) -> list[str]:
    """Remove what a quantizing process killed midway leaves in MODEL_DIR: its work folder and
    the int8 file it had not yet renamed into place (``checkpoint.write_atomic``'s
    ``.model.int8.onnx.*``). Returns their names. Only for when no other process quantizes
    there (the app runs one such job at a time). The ``model.onnx`` and ``export.json``
    temporaries are left alone: a live view or ``weldpool export-student`` may be writing them."""
    root = Path(model_dir)
    patterns = [f"{WORK_PREFIX}*", f".{INT8_ONNX_FILE}.*"]
    removed = []
    for pattern in patterns:
        for path in sorted(root.glob(pattern)):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
            removed.append(path.name)
    return removed


def _frame_ms(path: Path, frame: NDArray[np.float32]) -> float:
    """Median milliseconds of one frame through ``path`` on one thread."""
    from weldpool_core.student.export import onnx_session  # torch: loaded only when used

    session = onnx_session(path, threads=1)
    session.run(None, {"image": frame})
    times = []
    for _ in range(TIMING_RUNS):
        start = time.perf_counter()
        session.run(None, {"image": frame})
        times.append(time.perf_counter() - start)
    return round(1000.0 * float(np.median(times)), 2)


@dataclass(frozen=True)
class QuantizeResult:
    """The int8 file and how far it is from the float student on the check frames.

    Attributes:
        path: ``model.int8.onnx``.
        calibration_frames / check_frames: how many frames calibrated / checked it.
        mean_iou / min_iou: the int8 masks' IoU with the float ones (0.5 threshold).
        keypoint_px: median over check frames of the largest distance between a float
            keypoint and its nearest int8 one, in frame pixels (None without keypoints).
        mask_difference: mean absolute difference of the mask probabilities.
        float_ms / int8_ms: one frame's inference on one thread of this machine, median of
            ``TIMING_RUNS`` (what the int8 file saves here).
        weights_sha256: the float weights it was made from (``current_record``).
    """

    path: Path
    calibration_frames: int
    check_frames: int
    mean_iou: float
    min_iou: float
    keypoint_px: float | None
    mask_difference: float
    float_ms: float
    int8_ms: float
    weights_sha256: str = ""

    def as_dict(self) -> dict[str, Any]:
        """The record written to ``export.json``."""
        record = asdict(self)
        record["file"] = self.path.name
        del record["path"]
        return record


class _Frames:
    """ONNX Runtime's calibration reader: one frame at a time from an N×3×S×S batch."""

    def __init__(self, batch: NDArray[np.float32]) -> None:
        self._frames: Iterator[NDArray[np.float32]] = iter(batch)

    def get_next(self) -> dict[str, NDArray[np.float32]] | None:
        frame = next(self._frames, None)
        return None if frame is None else {"image": frame[None]}


def quantize_onnx(source: Path, target: Path, calibration: NDArray[np.float32]) -> None:
    """Write ``target``: ``source`` with int8 weights and uint8 activations (QDQ), ranges
    calibrated on the N×3×S×S ``calibration`` frames. Not checked: ``quantize_student`` is
    the way to make a student's int8 file."""
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(_Frames, CalibrationDataReader):  # type: ignore[misc]  # ORT is untyped
        pass

    work_dir = tempfile.TemporaryDirectory(dir=target.parent, prefix=WORK_PREFIX)
    with _quiet_quantizer(), work_dir as work:
        prepared = Path(work) / "prepared.onnx"
        # auto_merge: a skip connection adds an upsampled map to an encoder map whose sizes
        # the symbolic inference names apart (they are equal); without it inference gives up.
        try:
            quant_pre_process(str(source), str(prepared), auto_merge=True)
        except Exception as exc:  # ORT raises bare Exceptions from its shape inference
            raise InvalidInputError(
                f"ONNX Runtime could not prepare this student for int8 ({exc})."
            ) from exc

        def write(path: Path) -> None:
            quantize_static(
                str(prepared),
                str(path),
                Reader(calibration),
                quant_format=QuantFormat.QDQ,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
                per_channel=True,
                # 7-bit weights: x86 CPUs without VNNI (AVX2, AVX-512F) multiply u8 by s8 in
                # pairs summed into 16 bits, which saturates with 8-bit weights (ORT's
                # quantization guide). Seen here on an AVX2-only EPYC: masks at IoU 0.966 with
                # the float ones (refused by the check), 0.979 in 7 bits. The file may run on
                # another CPU than the one that made it.
                reduce_range=True,
                calibrate_method=CalibrationMethod.MinMax,
            )

        checkpoint.write_atomic(target, write)


class _FromOnnxRuntime(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "onnxruntime" not in record.pathname


@contextlib.contextmanager
def _quiet_quantizer() -> Iterator[None]:
    """Keep the quantizer's advice off the logs: it logs on the root logger (``logging.info``),
    so a filter there drops only records from ONNX Runtime's files; its named loggers are
    raised to errors. Other code's records pass."""
    root, named = logging.getLogger(), logging.getLogger("onnxruntime")
    only_ours, level = _FromOnnxRuntime(), named.level
    root.addFilter(only_ours)
    named.setLevel(logging.ERROR)
    try:
        yield
    finally:
        root.removeFilter(only_ours)
        named.setLevel(level)


def _keypoint_distance(float_points: NDArray[Any], int8_points: NDArray[Any]) -> float | None:
    """The largest distance from a keypoint of either set to the nearest of the other."""
    if not len(float_points) or not len(int8_points):
        return None
    distances = np.linalg.norm(float_points[:, None, :] - int8_points[None, :, :], axis=2)
    return float(max(distances.min(axis=1).max(), distances.min(axis=0).max()))


def compare(
    float_outputs: Sequence[NDArray[np.float32]],
    int8_outputs: Sequence[NDArray[np.float32]],
    geometries: Sequence[FrameGeometry],
    config: StudentConfig,
) -> tuple[list[float], list[float], float]:
    """Per frame the masks' IoU and the keypoints' distance, and the mean probability
    difference, of two students' (mask, heatmap) batches."""
    from weldpool_core.student.predict import frame_keypoints

    float_masks, float_heatmaps = float_outputs
    int8_masks, int8_heatmaps = int8_outputs
    ious: list[float] = []
    distances: list[float] = []
    for index, geometry in enumerate(geometries):
        rows, columns = geometry.inner_rows, geometry.inner_columns
        ious.append(
            iou(float_masks[index][rows, columns] >= 0.5, int8_masks[index][rows, columns] >= 0.5)
        )
        distance = _keypoint_distance(
            frame_keypoints(float_masks[index], float_heatmaps[index], geometry, config),
            frame_keypoints(int8_masks[index], int8_heatmaps[index], geometry, config),
        )
        if distance is not None:
            distances.append(distance)
    difference = float(np.abs(np.asarray(float_masks) - np.asarray(int8_masks)).mean())
    return ious, distances, difference


def quantize_student(model_dir: str | Path, images: Sequence[NDArray[Any]]) -> QuantizeResult:
    """Write MODEL_DIR's ``model.int8.onnx`` calibrated on ``images`` (frames of the camera,
    RGB or gray), checked against the float student (see the module doc).

    Raises InvalidInputError with fewer than ``MIN_FRAMES`` frames, and when the int8 masks
    differ from the float ones by more than the module's limits (nothing is written then: an
    int8 file made before stays, with its record).
    """
    from weldpool_core.student.predict import frames_to_batch

    if len(images) < MIN_FRAMES:
        raise InvalidInputError(
            f"Quantizing needs at least {MIN_FRAMES} frames of the camera (half calibrate, half "
            f"check the int8 model); {len(images)} given."
        )
    root = Path(model_dir)
    config = checkpoint.read_student_config(root)
    from weldpool_core.student.export import ensure_onnx, onnx_session  # torch, when used

    ensure_onnx(root)
    batch_tensor, geometries = frames_to_batch(images, config)
    batch = batch_tensor.numpy()
    calibration, check = batch[0::2], batch[1::2]
    path = root / INT8_ONNX_FILE
    found: list[QuantizeResult] = []

    def write(candidate: Path) -> None:  # checked before it takes the file's name
        quantize_onnx(root / ONNX_FILE, candidate, calibration)
        float_session, int8_session = onnx_session(root / ONNX_FILE), onnx_session(candidate)
        float_outputs = float_session.run(None, {"image": check})
        int8_outputs = int8_session.run(None, {"image": check})
        ious, distances, difference = compare(float_outputs, int8_outputs, geometries[1::2], config)
        result = QuantizeResult(
            path=path,
            calibration_frames=len(calibration),
            check_frames=len(check),
            mean_iou=round(float(np.mean(ious)), 4),
            min_iou=round(float(np.min(ious)), 4),
            keypoint_px=round(float(np.median(distances)), 2) if distances else None,
            mask_difference=round(difference, 5),
            float_ms=_frame_ms(root / ONNX_FILE, check[:1]),
            int8_ms=_frame_ms(candidate, check[:1]),
            weights_sha256=weights_digest(root),
        )
        if result.mean_iou < MIN_MEAN_IOU or result.min_iou < MIN_FRAME_IOU:
            raise InvalidInputError(
                f"The int8 student's masks differ from the float student's (IoU "
                f"{result.mean_iou:.3f} on average, {result.min_iou:.3f} at worst, over "
                f"{result.check_frames} frames; needed {MIN_MEAN_IOU} and {MIN_FRAME_IOU}); it "
                "was not kept."
            )
        found.append(result)

    checkpoint.write_atomic(path, write)
    result = found[0]
    record = checkpoint.read_json(root / EXPORT_FILE) if (root / EXPORT_FILE).is_file() else {}
    record["int8"] = result.as_dict()
    checkpoint.write_json(root / EXPORT_FILE, record)
    return result
