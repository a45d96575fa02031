"""The int8 student: kept only when its masks agree with the float student's, and streamed."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest

from tests.core.student.common import TINY_FRAME, TINY_STUDENT
from tests.helpers import run_cli, write_video
from weldpool_core.cell.stream import FrameSource, StreamStudent, run_stream
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import heatmap_from_mask
from weldpool_core.student.checkpoint import EXPORT_FILE, INT8_ONNX_FILE
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.export import export_student
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.quantize import compare, quantize_student
from weldpool_core.student.train import TrainResult
from weldpool_core.synth import synth_frame


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory: pytest.TempPathFactory, sure_student: TrainResult) -> Path:
    """The tiny student trained long enough (800 steps) for crisp masks: int8 can match it
    (IoU 0.99 over seeds and thread counts; after 100 steps, 0.965 to 0.99)."""
    out = Path(shutil.copytree(sure_student.model_dir, tmp_path_factory.mktemp("int8") / "model"))
    export_student(out, ["onnx"])
    return out


def _camera_frames(count: int = 12) -> list[np.ndarray]:
    """Frames the student never trained on (other weld runs of the same synthetic camera)."""
    return [synth_frame(seed, TINY_FRAME, 0.0).image for seed in range(100, 100 + count)]


@pytest.mark.parametrize("source", ["mask", "heatmap"])
def test_compare_measures_masks_on_the_frame_and_keypoints_in_frame_pixels(source: str) -> None:
    """A pool moved 4 model pixels to the right: IoU of the two discs, and every keypoint
    6 frame pixels away (the 96-wide frame is 64 model pixels wide: 1.5 px per model pixel),
    read from either output."""
    config = StudentConfig(keypoints=source)  # type: ignore[arg-type]
    geometry = FrameGeometry.fit(64, 96, 64)
    mask = np.zeros((64, 64), np.float32)
    cv2.circle(mask, (30, 32), 12, 1.0, -1)
    moved = np.roll(mask, 4, axis=1)
    heatmap = heatmap_from_mask(mask).heatmap[:, :, 0].astype(np.float32)
    outputs = (np.stack([mask]), np.stack([heatmap]))
    same, distances, difference = compare(outputs, outputs, [geometry], config)
    assert same == [1.0] and distances == [0.0] and difference == 0.0
    shifted = (np.stack([moved]), np.stack([np.roll(heatmap, 4, axis=1)]))
    ious, distances, difference = compare(outputs, shifted, [geometry], config)
    overlap = np.count_nonzero((mask > 0) & (moved > 0))
    expected = overlap / (2 * np.count_nonzero(mask) - overlap)
    assert ious == [pytest.approx(expected)] and expected < 0.8
    assert distances == [pytest.approx(6.0, abs=0.05)]
    assert difference == pytest.approx(np.abs(mask - moved).mean())


def test_an_int8_student_is_kept_when_its_masks_agree_and_streams_like_the_float_one(
    model_dir: Path, tmp_path: Path
) -> None:
    result = quantize_student(model_dir, _camera_frames())
    assert result.path == model_dir / INT8_ONNX_FILE and result.path.is_file()
    assert (result.calibration_frames, result.check_frames) == (6, 6)
    assert result.mean_iou >= 0.97 and result.min_iou >= 0.9 and result.mask_difference > 0
    assert result.float_ms > 0 and result.int8_ms > 0
    record = json.loads((model_dir / EXPORT_FILE).read_text())["int8"]
    assert record["file"] == INT8_ONNX_FILE and record["mean_iou"] == result.mean_iou
    graph = onnx.load(str(result.path)).graph
    kinds = {node.op_type for node in graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= kinds  # really quantized, not a copy
    assert any(t.data_type == onnx.TensorProto.INT8 for t in graph.initializer)

    video = write_video(tmp_path / "run.avi", 6)
    masks = {}
    for int8 in (False, True):
        student = StreamStudent(model_dir, "onnx", "cpu", threads=1, int8=int8)
        with FrameSource(str(video), prepare=student.prepare) as source:
            masks[int8] = [r.mask_probability >= 0.5 for r in run_stream(source, student)]
    assert len(masks[True]) == 6
    for ours, theirs in zip(masks[True], masks[False], strict=True):
        union = np.count_nonzero(ours | theirs)
        assert union == 0 or np.count_nonzero(ours & theirs) / union >= 0.9
    with pytest.raises(InvalidInputError, match="frame by frame"):
        StreamStudent(model_dir, "torch", int8=True)


def test_a_student_without_skips_quantizes_too(
    sure_latent_student: TrainResult, tmp_path: Path
) -> None:
    """Both layouts quantize. The tiny student the tests above quantize has the default two
    skips, whose additions survive ONNX Runtime's shape inference (auto_merge); one without
    skips (everything it draws through its latent) passes the same check."""
    assert TINY_STUDENT.skips == 2
    folder = Path(shutil.copytree(sure_latent_student.model_dir, tmp_path / "model"))
    export_student(folder, ["onnx"])
    result = quantize_student(folder, _camera_frames())
    assert result.path.is_file() and result.mean_iou >= 0.97
    kinds = {node.op_type for node in onnx.load(str(result.path)).graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= kinds


def test_an_int8_student_calibrated_on_the_wrong_frames_is_refused(
    model_dir: Path, tmp_path: Path
) -> None:
    """Calibrated on underexposed frames (the ranges of a dark camera), checked on bright ones:
    its masks disagree, so nothing is written; the int8 file made before, and its record, stay."""
    folder = tmp_path / "model"
    folder.mkdir()
    for path in model_dir.iterdir():
        (folder / path.name).write_bytes(path.read_bytes())
    frames = _camera_frames()
    if not (folder / INT8_ONNX_FILE).is_file():  # this test alone: make the earlier one
        quantize_student(folder, frames)
    earlier = (folder / INT8_ONNX_FILE).read_bytes()
    record = json.loads((folder / EXPORT_FILE).read_text())
    names = sorted(p.name for p in folder.iterdir())
    dark = [frame // 8 if index % 2 == 0 else frame for index, frame in enumerate(frames)]
    with pytest.raises(InvalidInputError, match="differ from the float student's"):
        quantize_student(folder, dark)
    assert (folder / INT8_ONNX_FILE).read_bytes() == earlier
    assert json.loads((folder / EXPORT_FILE).read_text()) == record
    assert sorted(p.name for p in folder.iterdir()) == names  # no temporary file left
    with pytest.raises(InvalidInputError, match="at least 4 frames"):
        quantize_student(folder, frames[:3])
    (folder / INT8_ONNX_FILE).unlink()
    with pytest.raises(InvalidInputError, match=r"no model\.int8\.onnx"):
        StreamStudent(folder, "onnx", int8=True)


def test_a_stale_int8_file_is_refused_and_dropped_once_the_weights_change(
    model_dir: Path, tmp_path: Path
) -> None:
    """A folder trained further after its int8 file was made: streaming int8 is refused (it
    would run the old network) and the next export removes the stale file and its record."""
    import torch

    from weldpool_core.student import checkpoint

    folder = tmp_path / "model"
    folder.mkdir()
    for path in model_dir.iterdir():
        (folder / path.name).write_bytes(path.read_bytes())
    quantize_student(folder, _camera_frames())
    StreamStudent(folder, "onnx", int8=True)  # current: it opens
    model = checkpoint.load_student(folder)
    with torch.no_grad():
        next(model.parameters()).add_(0.01)
    checkpoint.save_weights(folder, model)
    with pytest.raises(InvalidInputError, match="was made from other weights"):
        StreamStudent(folder, "onnx", int8=True)
    export_student(folder, ["onnx"])
    assert not (folder / INT8_ONNX_FILE).exists()
    assert "int8" not in json.loads((folder / EXPORT_FILE).read_text())


def test_the_cli_quantizes_on_a_video_and_streams_the_int8_student(
    model_dir: Path, tmp_path: Path
) -> None:
    video = write_video(tmp_path / "camera.avi", 12)
    stills = tmp_path / "stills"
    stills.mkdir()
    for index, frame in enumerate(_camera_frames(6)):
        cv2.imwrite(str(stills / f"f{index}.png"), frame)
    made = run_cli(
        "export-student", str(model_dir), "--format", "onnx-int8", "--calibrate", str(stills),
        "--calibrate", str(video), "--calibrate-frames", "12",
    )  # fmt: skip
    assert made.returncode == 0, made.stderr
    report = json.loads(made.stdout)
    assert report["files"] == {"onnx-int8": str(model_dir / INT8_ONNX_FILE)}
    assert report["int8"]["calibration_frames"] + report["int8"]["check_frames"] == 12
    streamed = run_cli("stream", str(video), "--model", str(model_dir), "--int8", "--quiet")
    assert streamed.returncode == 0, streamed.stderr
    summary = json.loads(streamed.stderr.strip().splitlines()[-1])
    assert (summary["backend"], summary["frames"]) == ("onnx-int8", 12)
    missing = run_cli("export-student", str(model_dir), "--format", "onnx-int8")
    assert missing.returncode == 2
    assert "give --calibrate PATH" in missing.stderr
