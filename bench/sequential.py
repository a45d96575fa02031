"""Benchmark the sequential student against the per-frame one on the three real WAAM videos.

Run: ``.venv/bin/python bench/sequential.py [--folds 0mm 2mm mm] [--seeds 0]`` (about 8 minutes
per fold and seed here).

Leave one clip out: for each held-out clip, the default per-frame student is trained on the
other two clips' 6 labelled frames (``weldpool train``'s defaults), then its sequential cell on
the same two clips' videos (``weldpool train-sequential``'s defaults; no label of the held-out
clip is seen by either). On the held-out clip's video, every frame streamed in order (ONNX
Runtime, as ``weldpool stream`` runs it):

- accuracy at its 3 labelled frames: mIoU and mED (px, against Algorithm 1 on the true masks),
  per frame and sequential (which has seen every earlier frame of the video);
- jitter without labels: the median second difference of the keypoint tracks (px per frame),
  and of the pool's area (% of the mean area), per frame, with the one-euro filter, sequential,
  and sequential + one-euro;
- lag: the video panned back and forth at ``--speed`` px per frame (each frame shifted along x,
  40 frames each way, so the pool moves at a known speed and stays in view): how many frames the
  sequential keypoints (and the one-euro ones) trail the per-frame keypoints along the motion
  (``trail``), and how many the sequential pool's centroid trails the per-frame one.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from results import recorded

from weldpool_core.cell.smoothing import KeypointSmoother, SmoothingParams, jitter
from weldpool_core.cell.stream import StreamStudent
from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.metrics import proposal_quality
from weldpool_core.student.checkpoint import read_student_config
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.evaluate import labelled_frames
from weldpool_core.student.export import export_student
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import frame_keypoints
from weldpool_core.student.sequential import (
    SequentialConfig,
    has_sequential,
    train_sequential,
    video_clip,
)
from weldpool_core.student.train import TrainConfig, train_student
from weldpool_core.video import iter_video_frames

REPO = Path(__file__).resolve().parents[1]
CLIPS = ("0mm", "2mm", "mm")
TRACKING_ONLY = SmoothingParams(min_cutoff=1e6, beta=0.0)
PAN_PERIOD = 80
STREAMS: dict[tuple[Path, str, bool, float], np.ndarray] = {}
"""The pool centroid's track (T×1×2) of each stream run, by (model, clip, sequential, speed)."""


def shared_data() -> Path:
    return Path(os.environ.get("WELDPOOL_SHARED_DATA") or REPO.parent / "shared" / "data")


def video(clip: str) -> Path:
    return shared_data() / "waam" / "video" / f"compressed_{clip}.mp4"


def labels_by_clip() -> dict[str, dict[int, TrainingFrame]]:
    data = shared_data() / "waam"
    found: dict[str, dict[int, TrainingFrame]] = {}
    for frame in labelled_frames(data / "frames", data / "labels"):
        clip, index = frame.name.removeprefix("compressed_").rsplit("_f", 1)
        found.setdefault(clip, {})[int(index)] = frame
    return found


def stream(
    model: Path, clip: str, sequential: bool, speed: float = 0.0
) -> tuple[np.ndarray, np.ndarray, dict[int, Any]]:
    """Keypoint tracks (T×k×2, tracking only), pool areas (T) and, per frame index, the
    full-resolution mask and keypoints, of every frame of a clip's video (panned by ``speed``)."""
    student = StreamStudent(model, "onnx", sequential=sequential)
    tracker = KeypointSmoother(student.config.k, TRACKING_ONLY)
    rows, areas, outputs, centroids = [], [], {}, []
    for frame in iter_video_frames(video(clip)):
        gray = frame.pixels
        if speed:
            shift = np.float32([[1, 0, pan(frame.index, speed)], [0, 1, 0]])
            gray = cv2.warpAffine(gray, shift, (gray.shape[1], gray.shape[0]))
        bgr = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
        batch, geometry = student.prepare(bgr)
        mask, heatmap, _ = student(batch, geometry)
        points = frame_keypoints(mask, heatmap, geometry, student.config)
        tracked = tracker.update(points, frame.timestamp_s)
        rows.append([p if p is not None else [np.nan, np.nan] for p in tracked])
        full = np.asarray(geometry.map_to_frame(mask)) >= 0.5
        areas.append(float(full.sum()))
        ys, xs = np.nonzero(full)
        centroids.append([[xs.mean(), ys.mean()]] if len(xs) else [[np.nan, np.nan]])
        outputs[frame.index] = (full, points)
    STREAMS[(model, clip, sequential, speed)] = np.asarray(centroids, np.float64)
    return np.asarray(rows, np.float64), np.asarray(areas), outputs


def smooth(tracks: np.ndarray, fps: float = 15.0) -> np.ndarray:
    smoother = KeypointSmoother(tracks.shape[1], SmoothingParams())
    out = []
    for index, row in enumerate(tracks):
        points = row[~np.isnan(row).any(axis=1)]
        done = smoother.update(points, index / fps)
        out.append([p if p is not None else [np.nan, np.nan] for p in done])
    return np.asarray(out, np.float64)


def area_jitter(areas: np.ndarray) -> float:
    second = np.abs(areas[2:] - 2 * areas[1:-1] + areas[:-2])
    return float(100 * np.median(second) / max(np.mean(areas), 1.0))


def pan(index: int, speed: float, period: int = PAN_PERIOD) -> float:
    """The pan's x shift at frame ``index``: back and forth at ``speed`` px per frame (a triangle
    wave of ``period`` frames, so the pool stays in view)."""
    phase = index % period
    return speed * (phase if phase <= period // 2 else period - phase)


def trail(reference: np.ndarray, tracks: np.ndarray, speed: float) -> float:
    """Frames ``tracks`` trail ``reference`` along the pan (T×k×2 each, or T×1×2 centroids).

    Each reference track is paired with the track nearest to it on average (Hungarian: two
    students may number their keypoints differently); per pair, d = reference − track along x
    and the pan's velocity v are centred (a steady offset between two students is no lag), and
    the lag is the least-squares L in d ≈ L · v over all pairs, from frame 30 on."""
    from scipy.optimize import linear_sum_assignment

    velocity = np.array([pan(i, speed) - pan(i - 1, speed) for i in range(len(reference))])
    ref, other = reference[30:], tracks[30:]
    centres = np.nanmean(ref, axis=0), np.nanmean(other, axis=0)
    cost = np.linalg.norm(centres[0][:, None] - centres[1][None], axis=-1)
    rows, columns = linear_sum_assignment(np.nan_to_num(cost, nan=1e9))
    top = bottom = 0.0
    for row, column in zip(rows, columns, strict=True):
        d = ref[:, row, 0] - other[:, column, 0]
        keep = np.isfinite(d)
        if keep.sum() < 10:
            continue
        dd = d[keep] - d[keep].mean()
        vv = velocity[30:][keep] - velocity[30:][keep].mean()
        top += float((dd * vv).sum())
        bottom += float((vv**2).sum())
    return top / bottom if bottom else float("nan")


def accuracy(outputs: dict[int, Any], truth: dict[int, TrainingFrame]) -> tuple[float, float]:
    scored = {}
    for index, frame in truth.items():
        mask, points = outputs[index]
        true_points = heatmap_from_mask(frame.mask, HeatmapParams()).keypoints
        scored[str(index)] = (mask, points, frame.mask, true_points)
    quality = proposal_quality(scored)
    return float(quality["mIoU"]), float(quality["mED"])


def fold(
    held: str, seed: int, root: Path, speed: float, config: SequentialConfig, reuse: bool
) -> dict[str, Any]:
    labels = labels_by_clip()
    train_clips = [c for c in CLIPS if c != held]
    model = root / f"{held}-{seed}"
    per_frame_s = 0.0
    if not (model / "model.onnx").is_file():  # kept between runs with --models
        frames = [f for c in train_clips for f in labels[c].values()]
        start = time.perf_counter()
        train_student(frames, model, StudentConfig(), TrainConfig(device="cpu", seed=seed))
        export_student(model, ["onnx"])
        per_frame_s = time.perf_counter() - start
    config = replace(config, seed=seed)
    row: dict[str, Any] = {"fold": held, "seed": seed, "train_s": per_frame_s, "seq_s": 0.0}
    if not (reuse and has_sequential(model)):
        student = read_student_config(model)
        clips = [video_clip(video(c), labels[c], config, student=student) for c in train_clips]
        result = train_sequential(model, clips, config)
        row.update(seq_s=result.seconds, loss=(result.first_loss, result.last_loss))
    raw, raw_area, raw_out = stream(model, held, False)
    seq, seq_area, seq_out = stream(model, held, True)
    row["acc_frame"] = accuracy(raw_out, labels[held])
    row["acc_seq"] = accuracy(seq_out, labels[held])
    row["jitter"] = {
        "per frame": jitter(raw, "median"),
        "one-euro": jitter(smooth(raw), "median"),
        "sequential": jitter(seq, "median"),
        "sequential + one-euro": jitter(smooth(seq), "median"),
    }
    row["area"] = {"per frame": area_jitter(raw_area), "sequential": area_jitter(seq_area)}
    pan_raw, _, _ = stream(model, held, False, speed)
    pan_seq, _, _ = stream(model, held, True, speed)
    row["lag"] = {
        "centroid": trail(
            STREAMS[(model, held, False, speed)], STREAMS[(model, held, True, speed)], speed
        ),
        "one-euro": trail(pan_raw, smooth(pan_raw), speed),
        "sequential": trail(pan_raw, pan_seq, speed),
        "sequential + one-euro": trail(pan_raw, smooth(pan_seq), speed),
    }
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folds", nargs="+", default=list(CLIPS), choices=CLIPS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--speed", type=float, default=4.0, help="pan, px per frame")
    parser.add_argument("--models", type=Path, help="keep the per-frame students here")
    parser.add_argument("--steps", type=int, default=SequentialConfig.steps)
    parser.add_argument(
        "--reuse-cells", action="store_true", help="with --models: keep cells trained before"
    )
    parser.add_argument("--drift", type=float, default=SequentialConfig.drift)
    args = parser.parse_args()
    config = SequentialConfig(device="cpu", steps=args.steps, drift=args.drift)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        root = args.models or Path(scratch)
        for held in args.folds:
            for seed in args.seeds:
                row = fold(held, seed, root, args.speed, config, args.reuse_cells)
                rows.append(row)
                print(row, flush=True)
    print(
        "\n| held-out clip | seed | mIoU: per frame → sequential | mED px: per frame → sequential "
        "| keypoint jitter px: per frame / one-euro / sequential / sequential + one-euro "
        "| area jitter %: per frame → sequential "
        "| keypoint lag frames: one-euro / sequential / sequential + one-euro "
        "| pool centroid lag frames, sequential | cell training s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        j, lag, area = r["jitter"], r["lag"], r["area"]
        print(
            f"| {r['fold']} | {r['seed']} | {r['acc_frame'][0]:.3f} → {r['acc_seq'][0]:.3f} "
            f"| {r['acc_frame'][1]:.1f} → {r['acc_seq'][1]:.1f} "
            f"| {j['per frame']:.2f} / {j['one-euro']:.2f} / {j['sequential']:.2f} / "
            f"{j['sequential + one-euro']:.2f} "
            f"| {area['per frame']:.2f} → {area['sequential']:.2f} "
            f"| {lag['one-euro']:.2f} / {lag['sequential']:.2f} / "
            f"{lag['sequential + one-euro']:.2f} | {lag['centroid']:.2f} | {r['seq_s']:.0f} |"
        )


if __name__ == "__main__":
    with recorded(__file__):
        main()
