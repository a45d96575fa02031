"""Benchmark ``weldpool stream`` on the three real WAAM videos (1280×800): speed and steadiness.

Run: ``.venv/bin/python bench/stream.py [--model DIR] [--resnet18-model DIR] [--frames N]
[--repeats N] [--sizes light resnet18]`` (about twenty-five minutes here with both students).

Speed: for each student size (trained on the real labels: light, and resnet18 with
``--resnet18-model``, whose real masks make the work after inference what it is on a weld;
otherwise random weights), backend (ONNX Runtime int8 and float, PyTorch) and thread count (1,
all cores), the stream pipeline as the command runs it — decoding (one decoder thread, the
command's default) and pre-processing on the reader thread, inference, keypoints and geometry on
the main one — over the first N frames of each video, read as fast as possible. Frames per
second, p50 / p99 latency from a frame leaving the decoder to its record, and the ratio to the
inference-only floor (the same model on already prepared inputs, nothing else running). Each
row makes ``--repeats`` passes (3) over the three videos: fps is the median of its passes, p50 /
p99 of all their frames, the floor the median of its passes'.

int8: each trained student quantized (``weldpool export-student --format onnx-int8``) on frames
spread through the three videos, and its agreement with the float student on others.

Steadiness: a student trained on the 9 real labels (``--model``, else trained here with the
default settings, ~90 s) streams every frame of each video twice, per frame and with the
one-euro filter; jitter is the mean and the median second difference of the keypoint tracks
(px; the mean counts jumps of a keypoint to another part of the outline), the lag at
steady speed is how many frames the filter trails a keypoint moving 3 px per frame (the real
pool barely moves, so it is measured on a synthetic ramp at the videos' 15 fps), and the lag on
the real tracks is the shift that best aligns filtered and raw tracks.

What the outputs to a welding cell (OPC UA, MQTT, ZeroMQ) add to this: ``bench/cell_outputs.py``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from results import recorded

from weldpool_core.cell.smoothing import KeypointSmoother, SmoothingParams, jitter, lag_frames
from weldpool_core.cell.stream import FrameSource, StreamStudent, run_stream, summary
from weldpool_core.student.checkpoint import INT8_ONNX_FILE, ONNX_FILE, save_config, save_weights
from weldpool_core.student.export import export_student
from weldpool_core.student.model import STUDENT_SIZES, build_student
from weldpool_core.student.predict import frames_to_batch
from weldpool_core.student.quantize import quantize_onnx, quantize_student
from weldpool_core.video import spread_frames

REPO = Path(__file__).resolve().parents[1]
CLIPS = ("compressed_0mm", "compressed_2mm", "compressed_mm")


def shared_data() -> Path:
    return Path(os.environ.get("WELDPOOL_SHARED_DATA") or REPO.parent / "shared" / "data")


def videos() -> list[Path]:
    found = [shared_data() / "waam" / "video" / f"{clip}.mp4" for clip in CLIPS]
    missing = [str(p) for p in found if not p.is_file()]
    if missing:
        raise SystemExit(f"missing real videos: {', '.join(missing)}")
    return found


def calibration_frames(per_video: int = 16) -> list[np.ndarray]:
    """Frames spread evenly through each real video (what a user calibrates int8 on)."""
    return [frame for video in videos() for frame in spread_frames(video, per_video)]


def random_student(size: str, root: Path) -> Path:
    """A random-weight student of ``size`` saved, exported to ONNX and quantized to int8
    (calibrated on real frames; unchecked, as a random student's masks mean nothing)."""
    folder = root / size
    folder.mkdir(parents=True)
    config = STUDENT_SIZES[size]
    save_weights(folder, build_student(config, load_pretrained=False).model)
    save_config(folder, config, {})
    export_student(folder, ["onnx"])
    batch, _ = frames_to_batch(calibration_frames(8), config)
    quantize_onnx(folder / ONNX_FILE, folder / INT8_ONNX_FILE, batch.numpy())
    return folder


def floor_fps(student: StreamStudent, video: Path, runs: int = 50) -> float:
    """Inference alone on one prepared frame, repeated: the pipeline's ceiling."""
    with FrameSource(str(video), max_frames=1, prepare=student.prepare) as source:
        frame = next(iter(source))
    batch, geometry = frame.prepared
    student(batch, geometry)
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        student(batch, geometry)
        times.append(time.perf_counter() - start)
    return 1.0 / statistics.median(times)


def speed_row(model: Path, backend: str, threads: int, frames: int, repeats: int) -> dict[str, Any]:
    int8 = backend == "onnx-int8"
    student = StreamStudent(model, "onnx" if int8 else backend, "cpu", threads, int8=int8)
    results = []
    latencies: list[float] = []
    floors = []
    for _ in range(repeats):
        for video in videos():
            with FrameSource(
                str(video), max_frames=frames, prepare=student.prepare, decoder_threads=1
            ) as source:
                start = time.perf_counter()
                mine = [r.record["latency_ms"] for r in run_stream(source, student)]
                elapsed = time.perf_counter() - start
            results.append(summary(mine, len(mine), 0, elapsed))
            latencies += mine
        floors.append(floor_fps(student, videos()[0]))
    pooled = summary(latencies, len(latencies), 0, 1.0)
    fps = statistics.median(r["fps"] for r in results)
    floor = statistics.median(floors)
    return {
        "fps": fps,
        "p50": pooled["latency_p50_ms"],
        "p99": pooled["latency_p99_ms"],
        "floor": floor,
    }


def train_real(folder: Path) -> Path:
    from weldpool_core.student.evaluate import labelled_frames
    from weldpool_core.student.model import StudentConfig
    from weldpool_core.student.train import TrainConfig, train_student

    data = shared_data() / "waam"
    frames = labelled_frames(data / "frames", data / "labels")
    print(f"training the default student on {len(frames)} real labels …", flush=True)
    train_student(frames, folder, StudentConfig(), TrainConfig(device="cpu"))
    export_student(folder, ["onnx"])
    return folder


def tracks(model: Path, video: Path, params: SmoothingParams) -> np.ndarray:
    """T×k×2 keypoint tracks of a video through the smoother (NaN where a track is empty)."""
    student = StreamStudent(model, "onnx")
    smoother = KeypointSmoother(student.config.k, params)
    rows = []
    with FrameSource(str(video), prepare=student.prepare) as source:
        for result in run_stream(source, student, smoother=smoother):
            rows.append([p if p is not None else [np.nan, np.nan] for p in result.keypoints])
    return np.asarray(rows, np.float64)


def ramp_lag(params: SmoothingParams, fps: float = 15.0, speed: float = 3.0) -> float:
    """Frames the filter trails a keypoint moving ``speed`` px per frame, at steady state."""
    smoother = KeypointSmoother(1, params)
    trail = []
    for index in range(200):
        x = index * speed
        out = smoother.update(np.array([[x, 0.0]]), index / fps)
        if index >= 100 and out[0] is not None:
            trail.append((x - out[0][0]) / speed)
    return float(np.mean(trail))


def steadiness(model: Path) -> None:
    print("\nSteadiness (trained light student, ONNX Runtime, every frame of each video)\n")
    print(
        "| video | frames | mean jitter px: per frame → one-euro | median jitter px: per frame "
        "→ one-euro | median down | lag on real tracks |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    tracking_only = SmoothingParams(min_cutoff=1e6, beta=0.0)  # same tracks, no filtering
    default = SmoothingParams()
    downs = []
    for video in videos():
        raw = tracks(model, video, tracking_only)
        smooth = tracks(model, video, default)
        before, after = jitter(raw, "median"), jitter(smooth, "median")
        downs.append(1 - after / before)
        print(
            f"| {video.stem} | {len(raw)} | {jitter(raw):.2f} → {jitter(smooth):.2f} "
            f"| {before:.2f} → {after:.2f} | {1 - after / before:.0%} "
            f"| {lag_frames(raw, smooth)} frame(s) |",
            flush=True,
        )
    print(
        f"\nmedian jitter down {np.mean(downs):.0%} on average; lag at steady speed (3 px per "
        f"frame, 15 fps): {ramp_lag(default):.2f} frames "
        f"(beta 0: {ramp_lag(SmoothingParams(beta=0)):.2f})"
    )


def int8_agreement(model: Path, size: str) -> None:
    """Quantize the trained student on frames of the three videos and print the check."""
    result = quantize_student(model, calibration_frames(16))
    print(
        f"\n{size} int8 (calibrated on {result.calibration_frames} frames spread through the three "
        f"videos, checked on {result.check_frames} others): mask IoU with the float student "
        f"{result.mean_iou:.4f} on average, {result.min_iou:.4f} at worst; keypoints "
        f"{result.keypoint_px} px apart (median of each frame's largest); mask probability "
        f"{result.mask_difference:.5f} apart on average; one frame {result.int8_ms} ms against "
        f"{result.float_ms} ms on one thread\n",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--model",
        type=Path,
        help="a light student trained on the real labels (its folder gets a model.int8.onnx)",
    )
    parser.add_argument(
        "--resnet18-model", type=Path, help="a resnet18 student trained on the real labels"
    )
    parser.add_argument("--frames", type=int, default=300, help="frames per video for speed")
    parser.add_argument(
        "--repeats", type=int, default=3, help="passes over the videos per row (this VM is noisy)"
    )
    parser.add_argument("--sizes", nargs="+", default=["light", "resnet18"])
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as root:
        model = args.model or train_real(Path(root) / "real")
        if not (model / ONNX_FILE).is_file():
            export_student(model, ["onnx"])
        trained = {"light": model}
        if args.resnet18_model:
            trained["resnet18"] = args.resnet18_model
            if not (args.resnet18_model / ONNX_FILE).is_file():
                export_student(args.resnet18_model, ["onnx"])
        for size, folder in trained.items():
            int8_agreement(folder, size)
        if not args.skip_speed:
            head = (
                f"{args.frames} frames of each of the 3 videos, 1280×800, {args.repeats} passes; "
                f"{cores} cores"
            )
            print(f"Speed ({head})\n")
            print("| student | backend | threads | fps | p50 ms | p99 ms | floor fps | of floor |")
            print("|---|---|---:|---:|---:|---:|---:|---:|")
            for size in args.sizes:
                # trained students where there are (a random one's noisy masks make the
                # keypoints and geometry after inference ~2.5× dearer than a real pool's)
                weights = trained.get(size) or random_student(size, Path(root))
                for backend in ("onnx-int8", "onnx", "torch"):
                    for threads in sorted({1, cores}):
                        row = speed_row(weights, backend, threads, args.frames, args.repeats)
                        print(
                            f"| {size} | {backend} | {threads} | {row['fps']:.1f} | "
                            f"{row['p50']:.2f} | {row['p99']:.2f} | {row['floor']:.1f} | "
                            f"{row['fps'] / row['floor']:.0%} |",
                            flush=True,
                        )
        steadiness(model)


if __name__ == "__main__":
    with recorded(__file__):
        main()
